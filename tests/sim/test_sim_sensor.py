"""The camera sensor model (``sim.sensor``): the exposure as a gamma table and one scale per frame gives the direct
table's values within one level, the drawn-on bands cover every mark, and the noise offset is a pure function."""

import numpy as np
import pytest

from sim.sensor import (
    NOISE_PAD_PX,
    DirtyBands,
    expose,
    exposure_lut,
    exposure_scale,
    exposure_table,
    gamma_table,
    noise_offset,
)


@pytest.mark.parametrize("lighting", ["day", "dusk", "night"])
def test_gamma_table_then_scale_is_the_direct_exposure_within_one_level(lighting):
    values = np.arange(256, dtype=np.uint8).reshape(1, 256, 1).repeat(3, axis=2)
    apart = 0
    for t_s in np.linspace(0.0, 20.0, 41):
        direct = exposure_lut(float(t_s), 3, lighting)[values].astype(int)
        scaled = expose(gamma_table(lighting)[values], exposure_scale(float(t_s), 3, lighting)).astype(int)
        d = np.abs(scaled - direct)
        assert d.max() <= 1, (t_s, int(d.max()))
        apart += int(np.count_nonzero(d))
    assert apart / (41 * values.size) < 0.01  # only where the exact value lies within 1/256 of an integer


def test_dirty_bands_cover_every_mark_cut_to_the_image():
    bands = DirtyBands(100, 200, band_px=16)
    assert bands.spans() == []
    bands.mark(10.5, 5, 50.2, 20)  # rows 5-19: bands 0 and 1
    bands.mark(-30, 90, 400, 130)  # cut to the image: rows 90-99, every column
    bands.mark(60, 60, 60, 70)  # empty: nothing
    spans = bands.spans()
    assert spans == [(0, 16, 10, 51), (16, 32, 10, 51), (80, 96, 0, 200), (96, 100, 0, 200)]
    covered = np.zeros((100, 200), bool)
    for y1, y2, x1, x2 in spans:
        covered[y1:y2, x1:x2] = True
    assert covered[5:20, 10:51].all() and covered[90:100].all()
    bands.clear()
    assert bands.spans() == []


def test_noise_offset_is_a_pure_function_in_range():
    offsets = [noise_offset(7, k) for k in range(2000)]
    assert offsets == [noise_offset(7, k) for k in range(2000)]
    assert all(0 <= dx < NOISE_PAD_PX and 0 <= dy < NOISE_PAD_PX for dx, dy in offsets)
    assert len(set(offsets)) > 1000  # spread over the field, frame to frame
    assert noise_offset(8, 5) != noise_offset(7, 5) or noise_offset(8, 6) != noise_offset(7, 6)


def test_noise_slot_is_a_pure_function_over_every_slot():
    from sim.sensor import NOISE_SLOTS, noise_slot

    slots = [noise_slot(7, k) for k in range(4000)]
    assert slots == [noise_slot(7, k) for k in range(4000)]
    counts = np.bincount(slots, minlength=NOISE_SLOTS)
    assert len(counts) == NOISE_SLOTS and counts.min() > 4000 / NOISE_SLOTS * 0.8  # every slot, evenly
    assert [noise_slot(8, k) for k in range(50)] != slots[:50]  # another camera, another sequence
    repeats = sum(a == b for a, b in zip(slots, slots[1:], strict=False)) / (len(slots) - 1)
    assert repeats < 2 / NOISE_SLOTS  # frame to frame the noise changes (a repeat is 1 in NOISE_SLOTS)


@pytest.mark.parametrize("lighting", ["day", "dusk", "night"])
def test_kept_noisy_scene_scaled_is_the_exposure_then_the_noise_within_noise(lighting):
    """sim.sensor.noise_bank + expose_bank: the static scene at unit gain with a slot's noise, scaled by the frame's
    gain, against the frame's exposure table and then the same noise: the gain's share of the noise and a level of
    rounding apart, the noise itself where the value saturates; every slot's noise a different cut."""
    import cv2

    from sim.sensor import NOISE_SLOTS, add_noise, expose_bank, noise_bank, noise_field

    rng = np.random.default_rng(5)
    scene = rng.integers(0, 256, (90, 160, 3)).astype(np.uint8)
    field = noise_field(3, lighting, {"day": 2.5, "dusk": 4.0, "night": 6.0}[lighting], 90, 160)
    bank = noise_bank(cv2.LUT(scene, exposure_table(lighting, 1 / 256)), field, 3)
    assert len(bank) == NOISE_SLOTS and len({b.tobytes() for b in bank}) == NOISE_SLOTS
    for t_s in (0.0, 2.0, 5.0, 8.0):
        scale = exposure_scale(t_s, 3, lighting)
        for slot in (0, NOISE_SLOTS - 1):
            exposed = cv2.LUT(scene, exposure_table(lighting, scale))
            direct = add_noise(exposed.copy(), field, noise_offset(3, slot))
            d = expose_bank(bank[slot], scale).astype(int) - direct
            clear = (bank[slot] > 0) & (bank[slot] < 255) & (exposed < 255) & (direct > 0) & (direct < 255)
            assert clear.mean() > 0.9
            assert np.abs(d[clear]).max() <= 3, (t_s, slot)  # a level of rounding and 11 % of the noise
            assert (np.abs(d[clear]) > 1).mean() < 0.03, (t_s, slot)
            assert np.abs(d).max() <= 6 * {"day": 2.5, "dusk": 4.0, "night": 6.0}[lighting]  # saturated: the noise
            assert abs(d.mean()) < 0.5


def test_exposure_table_gives_the_two_pass_values():
    """One uint8 table pass over a frame's drawn pixels gives what the gamma table (to uint16) and the frame's scale
    gave, for every 0-255 value, lighting and a spread of scales (the renderer's dirty bands)."""
    import cv2

    values = np.arange(256, dtype=np.uint8).reshape(16, 16)
    values = np.dstack([values, values[::-1], values.T])
    for lighting in ("day", "dusk", "night"):
        for t_s in np.linspace(0.0, 9.0, 13):
            scale = exposure_scale(float(t_s), 3, lighting)
            two_pass = expose(cv2.LUT(values, gamma_table(lighting)), scale)
            np.testing.assert_array_equal(cv2.LUT(values, exposure_table(lighting, scale)), two_pass)


def test_halo_falloff_is_made_once_per_radius_and_read_only():
    """sim.render.effects.halo_falloff: the Gaussian a sprite is coloured from, cached by radius."""
    import numpy as np
    import pytest

    from sim.render.effects import halo_falloff

    f = halo_falloff(6)
    assert f is halo_falloff(6) and f.shape == (25, 25, 1) and f.dtype == np.float32
    assert f[12, 12, 0] == 1.0 and f[12, 24, 0] == pytest.approx(np.exp(-144 / (2 * 4.5 ** 2)), rel=1e-6)
    with pytest.raises(ValueError):
        f[0, 0, 0] = 2.0
