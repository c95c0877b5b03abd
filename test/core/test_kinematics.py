"""RV kinematics against the paper's Table 4."""

import math

import pytest
from reducer_twin.core.kinematics import effective_lever_radius, mesh_pass_rate, speed_table
from reducer_twin.core.kinematics import total_ratio
from reducer_twin.core.params import ReducerParams

# Paper Table 4, "Theoretical value" column, deg/s (and the ratio).
PAPER_SUN_DEG_S = 7290.0
PAPER_PLANET_DEG_S = 3645.0
PAPER_OUTPUT_DEG_S = 90.0
PAPER_RATIO = 81.0


@pytest.fixture
def geometry():
    return ReducerParams().geometry


def test_total_ratio_is_81(geometry):
    # Paper Table 4; i = 1 + (Zpl/Zs)*Zp = 1 + 2*40 (physics notes 1).
    assert total_ratio(geometry) == PAPER_RATIO


def test_speed_table_reproduces_table_4(geometry):
    s = speed_table(math.radians(PAPER_SUN_DEG_S), geometry)
    assert s.ratio == PAPER_RATIO
    assert math.degrees(s.sun_speed) == pytest.approx(PAPER_SUN_DEG_S, rel=1e-12)
    assert math.degrees(s.output_speed) == pytest.approx(PAPER_OUTPUT_DEG_S, rel=1e-12)
    # The paper's "planetary wheel" speed is the first-stage value w_in*Zs/Zpl.
    assert math.degrees(s.planet_speed) == pytest.approx(PAPER_PLANET_DEG_S, rel=1e-12)


def test_crank_turns_3600_deg_s_relative_to_the_carrier(geometry):
    s = speed_table(math.radians(PAPER_SUN_DEG_S), geometry)
    # Willis, first stage: w_crank - w_c = -(Zs/Zpl)*(w_sun - w_c) = -(18/36)*(7290 - 90).
    assert math.degrees(s.crank_speed_relative) == pytest.approx(3600.0, rel=1e-12)
    # Second stage: the disc turns with the carrier, the crank turns Zp times per output
    # revolution relative to it (Zp = Zc + 1, pins fixed): an independent relation.
    assert s.crank_speed_relative == pytest.approx(geometry.z_pins * s.output_speed, rel=1e-12)


def test_mesh_pass_rate_is_10_hz_at_90_deg_s(geometry):
    # Each of the 39 teeth meets 40 pins per output revolution: 40 * 0.25 rev/s.
    assert mesh_pass_rate(math.radians(90.0), geometry) == pytest.approx(10.0, rel=1e-12)
    assert mesh_pass_rate(-math.radians(90.0), geometry) == pytest.approx(10.0, rel=1e-12)
    s = speed_table(math.radians(PAPER_SUN_DEG_S), geometry)
    assert s.mesh_frequency == pytest.approx(10.0, rel=1e-12)


def test_effective_lever_radius_is_89_1_mm(geometry):
    # Physics notes 3: r_eff = a*i*Zs/Zpl = 2.2 mm * 81 / 2 = 89.1 mm (a*Zc = 85.8 mm would
    # be a simple cycloid drive).
    assert effective_lever_radius(geometry) == pytest.approx(89.1e-3, rel=1e-12)


def test_ratio_follows_the_tooth_counts():
    g = ReducerParams().with_overrides({'geometry.z_sun': 12, 'geometry.z_planet': 36}).geometry
    assert total_ratio(g) == pytest.approx(1.0 + 3.0 * 40.0, rel=1e-12)
    assert effective_lever_radius(g) == pytest.approx(2.2e-3 * (40.0 + 12.0 / 36.0), rel=1e-12)
