"""Label assignment and losses of the project's small vehicle detector (``models/train_detector.py``; YOLOX, Ge et
al. 2021): anchor points over strides 8/16/32, the fixed centre-sampling assigner and SimOTA (dynamic top-k anchor
points by a class + IoU cost, any level), GIoU, and the loss: BCE objectness over all anchor points, BCE classes with
target one-hot x IoU, 5 x (1 - GIoU) + L1 boxes over positives, normalised by the number of positives. Needs torch
(the ``train`` extra).
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F

STRIDES = (8, 16, 32)
N_CLASSES = 2
CENTRE_RADIUS = 1.5
SIMOTA_RADIUS = 2.5
LEVEL_MAX_SIDE_PX = (48.0, 112.0, math.inf)
"""A box goes to stride 8 if its longer side (input pixels) is below 48, to 16 below 112, else to 32."""


def anchor_points(hw: tuple[int, int]) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Grid (A, 2) in cells, stride (A,), level index (A,) in YOLOX order."""
    grids, strides, levels = [], [], []
    for i, s in enumerate(STRIDES):
        hs, ws = hw[0] // s, hw[1] // s
        yv, xv = torch.meshgrid(torch.arange(hs), torch.arange(ws), indexing="ij")
        grids.append(torch.stack([xv, yv], -1).reshape(-1, 2))
        strides.append(torch.full((hs * ws,), float(s)))
        levels.append(torch.full((hs * ws,), i))
    return torch.cat(grids).float(), torch.cat(strides), torch.cat(levels)


def assign(boxes: np.ndarray, grid: torch.Tensor, stride: torch.Tensor, level: torch.Tensor):
    """Centre sampling: -> (fg mask (A,), index of the matched box per anchor (A,))."""
    A = len(grid)
    if len(boxes) == 0:
        return torch.zeros(A, dtype=torch.bool), torch.zeros(A, dtype=torch.long)
    b = torch.from_numpy(boxes[:, 1:])
    centres = (grid + 0.5) * stride[:, None]  # (A, 2)
    bc = (b[:, :2] + b[:, 2:]) / 2  # (G, 2)
    side = (b[:, 2:] - b[:, :2]).max(dim=1).values
    lvl = torch.zeros(len(b), dtype=torch.long)
    for m in LEVEL_MAX_SIDE_PX[:-1]:
        lvl += (side >= m).long()
    lvl = lvl.clamp(max=len(STRIDES) - 1)
    s = stride[:, None]
    d = (centres[:, None, :] - bc[None]).abs()  # (A, G, 2)
    near = (d <= CENTRE_RADIUS * s[..., None]).all(-1)
    inside = ((centres[:, None, :] >= b[None, :, :2] - s[..., None]) &
              (centres[:, None, :] <= b[None, :, 2:] + s[..., None])).all(-1)
    ok = near & inside & (level[:, None] == lvl[None])
    # every box gets at least its nearest anchor point on its level
    dist = (d ** 2).sum(-1) + (level[:, None] != lvl[None]).float() * 1e12
    nearest = dist.argmin(0)
    ok[nearest, torch.arange(len(b))] = True
    area = ((b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1]))[None].expand(A, -1)
    cost = torch.where(ok, area, torch.full_like(area, float("inf")))
    match = cost.argmin(1)
    fg = ok.any(1)
    return fg, match


def giou(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """GIoU of xyxy box pairs (Rezatofighi et al. 2019)."""
    lt, rb = torch.max(a[:, :2], b[:, :2]), torch.min(a[:, 2:], b[:, 2:])
    inter = (rb - lt).clamp(min=0).prod(1)
    area_a, area_b = (a[:, 2:] - a[:, :2]).prod(1), (b[:, 2:] - b[:, :2]).prod(1)
    union = area_a + area_b - inter + 1e-7
    iou = inter / union
    elt, erb = torch.min(a[:, :2], b[:, :2]), torch.max(a[:, 2:], b[:, 2:])
    enc = (erb - elt).prod(1) + 1e-7
    return iou - (enc - union) / enc


def simota_assign(pred_xyxy: torch.Tensor, pred_obj: torch.Tensor, pred_cls: torch.Tensor, boxes: np.ndarray,
                  grid: torch.Tensor, stride: torch.Tensor):
    """SimOTA (YOLOX, Ge et al. 2021 sec. 2.2): candidates are anchor points whose centre lies in a box or
    within ``SIMOTA_RADIUS`` strides of its centre (any level); cost = class BCE of sqrt(obj * cls)
    + 3 (-log IoU) + a large penalty unless both in the box and near its centre; each box takes its
    ``dynamic_k = sum of its top-10 candidate IoUs`` (at least 1) cheapest points; a point claimed twice
    goes to its cheapest box. Inputs are detached predictions of one image.
    -> (fg mask (A,), matched box index per anchor (A,), IoU of each fg prediction with its box (n_fg,))."""
    A = len(grid)
    fg = torch.zeros(A, dtype=torch.bool)
    match = torch.zeros(A, dtype=torch.long)
    if len(boxes) == 0:
        return fg, match, torch.zeros(0)
    b = torch.from_numpy(boxes[:, 1:])
    centres = (grid + 0.5) * stride[:, None]
    in_box = ((centres[:, None] > b[None, :, :2]) & (centres[:, None] < b[None, :, 2:])).all(-1)  # (A, G)
    bc = (b[:, :2] + b[:, 2:]) / 2
    in_ctr = ((centres[:, None] - bc[None]).abs() < SIMOTA_RADIUS * stride[:, None, None]).all(-1)
    cand = (in_box | in_ctr).any(1)
    if not cand.any():
        return fg, match, torch.zeros(0)
    ci = torch.nonzero(cand).flatten()
    ious = box_iou(b, pred_xyxy[ci])  # (G, C)
    onehot = F.one_hot(torch.from_numpy(boxes[:, 0]).long(), N_CLASSES).float()  # (G, K)
    p = (pred_cls[ci].sigmoid() * pred_obj[ci, None].sigmoid()).sqrt().clamp(1e-6, 1 - 1e-6)  # (C, K)
    cls_cost = -(onehot[:, None] * p.log()[None] + (1 - onehot[:, None]) * (1 - p).log()[None]).sum(-1)
    both = (in_box & in_ctr)[ci].T  # (G, C)
    cost = cls_cost + 3.0 * -torch.log(ious + 1e-8) + 1e5 * (~both).float()
    k = min(10, len(ci))
    dyn_k = ious.topk(k, dim=1).values.sum(1).int().clamp(min=1)  # (G,)
    rank = cost.argsort(1).argsort(1)
    chosen = rank < dyn_k[:, None]  # (G, C)
    multi = chosen.sum(0) > 1
    if multi.any():
        best = torch.where(chosen, cost, torch.full_like(cost, float("inf"))).argmin(0)
        chosen[:, multi] = False
        chosen[best[multi], torch.nonzero(multi).flatten()] = True
    sel = chosen.any(0)
    gi = chosen.float().argmax(0)[sel]
    fg[ci[sel]] = True
    match[ci[sel]] = gi
    return fg, match, ious[gi, torch.nonzero(sel).flatten()]


def box_iou(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """IoU matrix (N, M) of xyxy boxes."""
    lt = torch.max(a[:, None, :2], b[None, :, :2])
    rb = torch.min(a[:, None, 2:], b[None, :, 2:])
    inter = (rb - lt).clamp(min=0).prod(-1)
    area_a = (a[:, 2:] - a[:, :2]).clamp(min=0).prod(-1)
    area_b = (b[:, 2:] - b[:, :2]).clamp(min=0).prod(-1)
    return inter / (area_a[:, None] + area_b[None] - inter + 1e-7)


def decode_boxes(out: torch.Tensor, grid: torch.Tensor, stride: torch.Tensor) -> torch.Tensor:
    """(..., A, 4) raw -> xyxy input px, exactly as ``rsu.detect.decode_yolox`` does at runtime."""
    xy = (out[..., :2] + grid) * stride[:, None]
    wh = torch.exp(out[..., 2:4].clamp(max=8)) * stride[:, None]
    return torch.cat([xy - wh / 2, xy + wh / 2], -1)


def detection_loss(raw: list[torch.Tensor], targets: list[np.ndarray], hw: tuple[int, int],
                   ignores: list[np.ndarray] | None = None, assigner: str = "simota"):
    """YOLOX losses: BCE objectness over all anchor points (but those inside an ignore box), BCE classes
    (target one-hot x IoU of the prediction with its box, YOLOX's IoU-aware class score) and 5 x (1 - GIoU)
    + L1 of the raw box over positives, normalised by the number of positives."""
    grid, stride, level = anchor_points(hw)
    out = torch.cat([o.flatten(2).permute(0, 2, 1) for o in raw], dim=1)  # (B, A, 7)
    B, A, _ = out.shape
    obj_t = torch.zeros(B, A)
    obj_w = torch.ones(B, A)
    pred_all = decode_boxes(out.detach(), grid, stride)
    centres = (grid + 0.5) * stride[:, None]
    box_p, box_t, box_raw, box_raw_t, cls_p, cls_t = [], [], [], [], [], []
    for i in range(B):
        if ignores is not None and len(ignores[i]):
            ig = torch.from_numpy(ignores[i])
            inside = ((centres[:, None] >= ig[None, :, :2]) & (centres[:, None] <= ig[None, :, 2:])).all(-1).any(1)
            obj_w[i, inside] = 0.0
        if assigner == "simota":
            fg, match, fg_iou = simota_assign(pred_all[i], out[i, :, 4].detach(), out[i, :, 5:].detach(), targets[i],
                                              grid, stride)
        else:
            fg, match = assign(targets[i], grid, stride, level)
            fg_iou = torch.ones(int(fg.sum()))
        if not fg.any():
            continue
        obj_t[i, fg] = 1.0
        obj_w[i, fg] = 1.0
        tb = torch.from_numpy(targets[i][match[fg].numpy()])
        o = out[i, fg]
        s = stride[fg][:, None]
        xy = (o[:, :2] + grid[fg]) * s
        wh = torch.exp(o[:, 2:4].clamp(max=8)) * s
        box_p.append(torch.cat([xy - wh / 2, xy + wh / 2], 1))
        box_t.append(tb[:, 1:])
        twh = (tb[:, 3:5] - tb[:, 1:3]).clamp(min=1.0)
        txy = (tb[:, 1:3] + tb[:, 3:5]) / 2
        box_raw.append(o[:, :4])
        box_raw_t.append(torch.cat([txy / s - grid[fg], torch.log(twh / s)], 1))
        cls_p.append(o[:, 5:])
        cls_t.append(F.one_hot(tb[:, 0].long(), N_CLASSES).float() * fg_iou.clamp(min=0.0)[:, None])
    n_fg = max(1.0, float(obj_t.sum()))
    loss_obj = (F.binary_cross_entropy_with_logits(out[..., 4], obj_t, reduction="none") * obj_w).sum() / n_fg
    if box_p:
        bp, bt = torch.cat(box_p), torch.cat(box_t)
        loss_iou = (1 - giou(bp, bt)).sum() / n_fg
        loss_l1 = F.l1_loss(torch.cat(box_raw), torch.cat(box_raw_t), reduction="sum") / n_fg
        loss_cls = F.binary_cross_entropy_with_logits(torch.cat(cls_p), torch.cat(cls_t), reduction="sum") / n_fg
    else:
        loss_iou = loss_l1 = loss_cls = out.sum() * 0
    total = 5.0 * loss_iou + loss_obj + loss_cls + loss_l1
    return total, {"iou": float(loss_iou.detach()), "obj": float(loss_obj.detach()), "cls": float(loss_cls.detach()),
                   "l1": float(loss_l1.detach()),
                   "fg": n_fg / B}
