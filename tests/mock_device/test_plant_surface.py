"""The plate surface: height formula, metal map (voids, kerfs), warp slopes of the scenarios."""

import itertools
import math

import pytest

from mock_device.plant import GAP_KERF, GAP_METAL, GAP_WIDE, PlateSurface, load_scenario
from mock_device.plant.scenario import KerfSpec, PlateSpec, VoidSpec, WaveSpec
from mock_device.plant.surface import distance_to_segment_mm


def test_height_is_top_plus_tilt_plus_waves() -> None:
    """z(x, y) = top + tilt about the origin + Σ A·sin(k·d + phase)."""
    plate = PlateSpec(
        top_mm=20.0,
        tilt_x_mm_per_m=2.0,
        tilt_y_mm_per_m=-1.0,
        waves=(WaveSpec(amplitude_mm=1.0, wavelength_mm=400.0, direction_deg=0.0, phase_deg=90.0),),
    )
    surface = PlateSurface(plate)
    assert surface.height_mm(0.0, 0.0) == pytest.approx(21.0)
    assert surface.height_mm(200.0, 0.0) == pytest.approx(20.0 + 0.4 - 1.0)
    assert surface.height_mm(100.0, 300.0) == pytest.approx(20.0 + 0.2 - 0.3 + 0.0, abs=1e-9)
    gx, gy = surface.gradient(100.0, 0.0)
    assert gx == pytest.approx(0.002 - 2 * math.pi / 400.0)
    assert gy == pytest.approx(-0.001)


def test_metal_map_knows_voids_kerfs_and_the_plate_edge() -> None:
    """No metal inside a void, within half a kerf width of an old kerf, or off the plate."""
    surface = PlateSurface(
        PlateSpec(size_x_mm=500.0, size_y_mm=300.0),
        kerfs=(
            KerfSpec(100.0, 0.0, 100.0, 200.0),
            KerfSpec(0.0, 250.0, 400.0, 250.0, width_mm=3.0),
        ),
        voids=(VoidSpec(300.0, 50.0, 320.0, 100.0), VoidSpec(400.0, 0.0, 403.0, 300.0)),
        default_kerf_width_mm=1.5,
        wide_void_mm=6.0,
    )
    assert surface.gap_kind(50.0, 50.0) == GAP_METAL
    assert surface.gap_kind(100.7, 50.0) == GAP_KERF
    assert surface.gap_kind(100.8, 50.0) == GAP_METAL
    assert surface.gap_kind(100.0, 200.7) == GAP_KERF, "round kerf end"
    assert surface.gap_kind(100.0, 201.0) == GAP_METAL
    assert surface.gap_kind(200.0, 251.4) == GAP_KERF
    assert surface.gap_kind(310.0, 75.0) == GAP_WIDE
    assert surface.gap_kind(401.0, 10.0) == GAP_KERF, "a 3 mm slot is a narrow gap"
    assert surface.gap_kind(-1.0, 10.0) == GAP_WIDE
    assert surface.gap_kind(10.0, 301.0) == GAP_WIDE
    assert not surface.is_metal(310.0, 75.0)
    assert surface.is_metal(50.0, 50.0)
    assert surface.distance_to_nearest_kerf_mm(103.0, 50.0) == pytest.approx(3.0)
    assert distance_to_segment_mm((3.0, 4.0), (0.0, 0.0), (0.0, 0.0)) == pytest.approx(5.0)


def test_warped_sheet_gives_10_to_30_volts_per_second_at_cut_speed() -> None:
    """Along the warped program at cut feed, the fixed-Z voltage slope peaks at 10-30 V/s."""
    scenario = load_scenario("warped_sheet")
    surface = PlateSurface(scenario.plate)
    feed_mm_s = scenario.material.cut_feed_mm_min / 60.0
    slope_v_per_mm = scenario.material.slope_v_per_mm
    corners = [(100.0, 100.0), (1100.0, 100.0), (1100.0, 600.0), (100.0, 600.0), (100.0, 100.0)]
    peak = 0.0
    for (x0, y0), (x1, y1) in itertools.pairwise(corners):
        length = math.hypot(x1 - x0, y1 - y0)
        ux, uy = (x1 - x0) / length, (y1 - y0) / length
        for i in range(int(length)):
            gx, gy = surface.gradient(x0 + ux * i, y0 + uy * i)
            peak = max(peak, abs(gx * ux + gy * uy) * feed_mm_s * slope_v_per_mm)
    assert 10.0 <= peak <= 30.0


def test_flat_scenarios_are_flat() -> None:
    """flat_clean has no tilt and no waves: the surface is the nominal top everywhere."""
    surface = PlateSurface(load_scenario("flat_clean").plate)
    assert {surface.height_mm(x, y) for x in (0.0, 600.0) for y in (0.0, 900.0)} == {20.0}
