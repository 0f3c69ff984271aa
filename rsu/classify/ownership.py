"""Which vehicle a lamp belongs to: the RSU measures lamps in a band grown above each track's box, and
in dense traffic one lamp, or its glow, falls in the bands of several tracks. These pure functions of the frame's
boxes decide which parts of a track's band are another vehicle's (:func:`band_exclusions`, :func:`farther_boxes`),
so that an EV's flashes count for the EV and not for the car beside it (:class:`rsu.classify.ev.TrackEvClassifier`,
which also holds back a flash-alone confirmation when a vehicle just ahead may own the lamps)."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from rsu.track.assoc import iou_matrix


def band_exclusions(k: int, boxes: np.ndarray, bounds: list[tuple[int, int, int, int] | None]
                    ) -> list[tuple[int, int, int, int]]:
    """The parts of track ``k``'s crop that belong to other vehicles, left out of its lamp band so that a lamp
    is counted for one vehicle only:
    - of every vehicle nearer the camera (its box's bottom edge lower in the image), its box (it occludes this
      one) and its crop above that box, except this box's rows nearer this box's top than that vehicle's top
      (:func:`rect_minus`; the rows split at the midpoint of the two tops, as a roof bar sits at its own vehicle's
      top). Without the exception a police car just ahead of a bus, its bar inside the bus's upward-grown crop,
      lost every flash to it and was never confirmed (ev_bench tuning seed 21376, ``ev_two_lanes_dense``, rsu1);
      the split keeps a nearer EV's bar, just above its box, out of a farther box that reaches down to its roof;
    - of every other vehicle whose crop overlaps this one, the columns nearer its box centre than this box's (the
      two crops split at the midpoint between the centres): without it a car beside an EV counts the EV's roof
      bar, which its own upward-grown crop takes in;
    - of every farther vehicle (bottom edge higher) seen above this box's top, its own box above that top: without
      it a truck or bus behind a car or an EV counts the tail lights or the light bar of the vehicle ahead, which
      its upward-grown band takes in (simulator tuning seeds 31372/91468: 4 false alerts)."""
    out: list[tuple[int, int, int, int]] = []
    box = boxes[k]
    own = (int(np.floor(box[0])), int(np.floor(box[1])), int(np.ceil(box[2])), int(np.ceil(box[3])))
    cx = 0.5 * (box[0] + box[2])
    for j, other in enumerate(boxes):
        ob = bounds[j]
        if j == k or ob is None:
            continue
        if other[3] > box[3]:
            top = min(max(int(np.floor(other[1])), ob[1]), ob[3])
            out.append((ob[0], top, ob[2], ob[3]))  # its box hides this vehicle
            # its crop above its box, except this box's rows nearer this box's top than the nearer one's top
            mid = int(round(0.5 * (box[1] + other[1])))
            out.extend(rect_minus((ob[0], ob[1], ob[2], top), (own[0], own[1], own[2], min(own[3], mid))))
            continue
        ocx = 0.5 * (other[0] + other[2])
        if ocx != cx:
            mid = int(round(0.5 * (cx + ocx)))
            out.append((mid, ob[1], ob[2], ob[3]) if ocx > cx else (ob[0], ob[1], mid, ob[3]))
        if other[1] < box[1] and other[2] > box[0] and other[0] < box[2]:
            # a farther vehicle seen above this one's roof: its own box, where it rises above this box's top,
            # is that vehicle (its tail lights, its light bar), not a roof bar of this one
            out.append((int(np.floor(other[0])), int(np.floor(other[1])), int(np.ceil(other[2])),
                        int(np.ceil(min(other[3], box[1])))))
    return out


def rect_minus(a: tuple[int, int, int, int], b: tuple[int, int, int, int]) -> list[tuple[int, int, int, int]]:
    """The xyxy rectangle ``a`` less the rectangle ``b``, as at most four rectangles (above, below, left and right of
    ``b``); none when ``a`` is empty."""
    x1, y1, x2, y2 = a
    if x2 <= x1 or y2 <= y1:
        return []
    bx1, by1, bx2, by2 = max(b[0], x1), max(b[1], y1), min(b[2], x2), min(b[3], y2)
    if bx2 <= bx1 or by2 <= by1:
        return [a]
    parts = [(x1, y1, x2, by1), (x1, by2, x2, y2), (x1, by1, bx1, by2), (bx2, by1, x2, by2)]
    return [p for p in parts if p[2] > p[0] and p[3] > p[1]]


def farther_boxes(k: int, boxes: np.ndarray) -> list[tuple[int, int, int, int]]:
    """The boxes of the farther vehicles (bottom edge higher) that rise above track ``k``'s box top and overlap its
    columns, left out of its *light-bar* measurement (not of the lamp-bright one): within this box's band such a
    vehicle's tail lights and red paint show where a roof bar would (a dark truck at night behind a car: the
    car's lit tail light inside the truck's box; simulator tuning seed 31372). The light-bar cues count only
    with a confident EV body, which a black truck at night can get; the lamp-bright flash of a sim EV behind a
    car is not affected. Above this box's top :func:`band_exclusions` leaves such a box out of both."""
    box = boxes[k]
    out = []
    for j, other in enumerate(boxes):
        if j != k and other[3] <= box[3] and other[1] < box[1] and other[2] > box[0] and other[0] < box[2]:
            out.append((int(np.floor(other[0])), int(np.floor(other[1])), int(np.ceil(other[2])),
                        int(np.ceil(other[3]))))
    return out


def rect_mask(bounds: tuple[int, int, int, int], rects: Iterable[tuple[int, int, int, int]]) -> np.ndarray | None:
    """A boolean mask of the crop ``bounds`` (xyxy pixels), True in the image rectangles ``rects``; None when none
    of them overlaps it."""
    xa, ya, xb, yb = bounds
    mask = None
    for ob in rects:
        if ob[0] >= xb or ob[2] <= xa or ob[1] >= yb or ob[3] <= ya:
            continue
        if mask is None:
            mask = np.zeros((yb - ya, xb - xa), bool)
        mask[max(ob[1] - ya, 0):ob[3] - ya, max(ob[0] - xa, 0):ob[2] - xa] = True
    return mask


def holds_nearer_vehicle(k: int, boxes: np.ndarray, fraction: float = 0.5) -> bool:
    """Does track ``k``'s box hold at least ``fraction`` of the box of a vehicle nearer the camera (its bottom edge
    lower in the image)? Boxes are visible parts, so such a box is two vehicles merged by the detector, not one seen
    again: it must not take over a lost EV's evidence (ev_bench seed 51100, ``night_ev``, rsu1: one box over the EV
    and the top of the truck behind it took over the EV's confirmed track and raised its alert at the truck's place)."""
    box = boxes[k]
    for j, other in enumerate(boxes):
        if j == k or other[3] <= box[3]:
            continue
        iw = min(box[2], other[2]) - max(box[0], other[0])
        ih = min(box[3], other[3]) - max(box[1], other[1])
        area = (other[2] - other[0]) * (other[3] - other[1])
        if iw > 0 and ih > 0 and area > 0 and iw * ih >= fraction * area:
            return True
    return False


def hidden_behind_nearer(box, boxes: np.ndarray, fraction: float = 0.5, max_iou: float = 0.3) -> bool:
    """Is the bottom edge of ``box`` (a lost track's box, moved on), where its vehicle meets the road, behind one of
    ``boxes`` whose bottom edge is lower in the image, over at least ``fraction`` of its width: a vehicle nearer the
    camera hides the lost one's lower body, so the detector sees at most its roof, and it may still be there? A box
    that overlaps ``box`` by IoU ``max_iou`` or more may be the lost vehicle itself, seen again: it hides nothing."""
    box = np.asarray(box, float)
    boxes = np.asarray(boxes, float).reshape(-1, 4)
    width = box[2] - box[0]
    if width <= 0 or not len(boxes):
        return False
    covered_w = np.minimum(box[2], boxes[:, 2]) - np.maximum(box[0], boxes[:, 0])
    hiding = (boxes[:, 3] > box[3]) & (boxes[:, 1] < box[3]) & (covered_w >= fraction * width)
    return bool(np.any(hiding & (iou_matrix(box[None], boxes)[0] < max_iou)))


def above_top(rects: list[tuple[int, int, int, int]], box) -> list[tuple[int, int, int, int]]:
    """The parts of ``rects`` (farther vehicles' boxes, :func:`farther_boxes`) above ``box``'s top edge: within its
    own box a vehicle hides the farther ones, so only there, in the band its crop grows above the box for the roof
    bar, are their pixels theirs (the rule :func:`band_exclusions` applies to the lamp band)."""
    top = int(np.ceil(box[1]))
    return [(x1, y1, x2, min(y2, top)) for x1, y1, x2, y2 in rects if y1 < top]


def blank_rects(crop: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    """``crop`` with the pixels of ``mask`` (another vehicle's: :func:`rect_mask` of :func:`above_top`) set to the
    median colour of the rest, so that the EV-body classifier scores this vehicle and not the one seen above it;
    ``crop`` itself when there is nothing to blank (or nothing left around it). A black truck that entered the view
    just behind an ambulance, its crop grown over the ambulance, scored 0.68 with the ambulance's box in it, 0.40 with
    that box blanked above the truck's top, 0.18 blanked whole; the whole box is not blanked, because a large vehicle
    behind this one (a bus behind an ambulance) has a box that takes in this one's roof and upper body. ev_bench tuning
    seeds 16790/36545/51100/68157/57097 (every scenario): of 10 EV crops with a farther box, 6 scored >= 0.5 as they are
    and 6 blanked above the top; of 84 other-vehicle crops, 15 and 9."""
    if mask is None or not mask.any() or mask.all():
        return crop
    out = crop.copy()
    out[mask] = np.median(crop[~mask], axis=0).astype(crop.dtype)
    return out
