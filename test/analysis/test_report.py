"""The analysis report: PNG plots and one self-contained HTML page."""

import base64
import copy
import re

import numpy as np
import pytest
from reducer_twin.analysis.pipeline import analyze_bag
from reducer_twin.analysis.report import _figures, PLOTS, wear_axis_limits, write_report
from reducer_twin.analysis.simulate import simulate_bag, SimulationSpec
from reducer_twin.cli import main
from reducer_twin.core.errors import BagError
from reducer_twin.core.units import ARCMIN
from reducer_twin.msg_adapters.layouts import TE_FEATURES

PNG = b'\x89PNG\r\n\x1a\n'


@pytest.fixture(scope='module')
def result(tmp_path_factory):
    """Analyse a small simulated bag of two joints (ground truth included)."""
    root = tmp_path_factory.mktemp('report')
    spec = SimulationSpec(hours=1000.0, aging_factor=120_000.0, joints=2, rate_hz=200.0,
                          seed=4, wear_rate_scales=(1.0, 1.5))
    simulate_bag(root / 'bag', spec)
    return analyze_bag(root / 'bag', root / 'derived')


def test_the_report_has_every_plot_as_png_and_an_html_page_embedding_them(result, tmp_path):
    page = write_report(result, tmp_path / 'r')
    assert page == tmp_path / 'r' / 'index.html'
    text = page.read_text(encoding='utf-8')
    for stem, title in PLOTS:
        png = (tmp_path / 'r' / f'{stem}.png').read_bytes()
        assert png.startswith(PNG) and len(png) > 5000
        assert title in text
        # Self-contained: the page carries the same image, no link to a file.
        assert base64.b64encode(png).decode('ascii') in text
    assert not re.search(r'src="(?!data:)', text)
    for joint in ('joint_1', 'joint_2'):
        assert f'<td>{joint}</td>' in text
        s = result.joints[joint].summary()    # the lost motion with its sd, as the wear
        assert f'<td>{s["lost_motion_arcmin"]:.3f} ± {s["lost_motion_std_arcmin"]:.3f}</td>' \
            in text
    assert 'true wear' in text and 'aging factor 120000' in text


def test_the_cli_writes_the_report_beside_the_derived_bag(result, tmp_path, capsys):
    code = main(['analyze', str(result.bag), '--out', str(tmp_path / 'd'), '--report',
                 str(tmp_path / 'rep')])
    out = capsys.readouterr().out
    assert code == 0
    assert f'report: {tmp_path / "rep" / "index.html"}' in out
    assert sorted(p.name for p in (tmp_path / 'rep').iterdir()) == sorted(
        ['index.html'] + [f'{stem}.png' for stem, _ in PLOTS])


def test_a_report_directory_that_cannot_be_made_is_a_bag_error(result, tmp_path):
    blocker = tmp_path / 'file'
    blocker.write_text('x')
    with pytest.raises(BagError, match='cannot write the report'):
        write_report(result, blocker / 'sub')


def test_the_wear_axis_leaves_out_the_prior_of_the_first_windows_and_shows_zero():
    wear = np.array([1.0, 2.0, 0.5, 3.0, 3.2, 3.4, 3.6, 3.8, 4.0, 4.2])
    std = np.array([12.0, 9.0, 5.0, 0.3, 0.3, 0.3, 0.3, 0.3, 0.3, np.nan])
    bottom, top = wear_axis_limits(wear, std)
    assert bottom < 0.0 < 3.0 < top
    assert top == pytest.approx(1.1 * (4.0 + 0.6))
    assert wear_axis_limits(wear[:3], std[:3]) is None


def test_the_wear_band_never_goes_below_zero_wear(result):
    figures = dict(_figures(result, limit=3.0 * ARCMIN))
    ax = figures['wear'].axes[0]
    bands = [c for c in ax.collections if c.get_label().endswith('±2σ')]
    assert len(bands) == 2
    for band in bands:
        ys = np.concatenate([p.vertices[:, 1] for p in band.get_paths()])
        assert ys.min() >= 0.0
    assert ax.get_ylim()[0] <= 0.0


def test_a_joint_not_observed_gets_no_estimate_curve_only_its_readings(result):
    # Beside NOT OBSERVED in the table, the plots drew the prior's guess: on a heavy duty a
    # lost motion rising to the limit and a remaining life of 0 h.
    blind = copy.copy(result)
    blind.joints = dict(result.joints)
    blind.joints['joint_2'] = copy.copy(result.joints['joint_2'])
    blind.joints['joint_2'].reason = 'the link angle follows the motor angle'
    assert not blind.joints['joint_2'].observed
    figures = dict(_figures(blind, limit=3.0 * ARCMIN))
    for stem in ('lost_motion', 'wear', 'remaining_life'):
        ax = figures[stem].axes[0]
        labels = [a.get_label() for a in (*ax.lines, *ax.collections)]
        assert 'joint_2: not observed, no estimate' in labels, stem
        assert not [x for x in labels if x.startswith('joint_2 ') and 'observed per' not in x]
        assert any(x.startswith('joint_1 ') for x in labels), stem
    lines = figures['lost_motion'].axes[0].lines
    assert 'joint_2 observed per window' in [line.get_label() for line in lines]


def test_readings_on_a_new_units_bound_are_drawn_apart_as_not_used(result):
    bound = copy.copy(result)
    bound.joints = dict(result.joints)
    res = bound.joints['joint_1'] = copy.copy(result.joints['joint_1'])
    res.features = res.features.copy()
    res.features[:3, TE_FEATURES.fields.index('wear_fit_m')] = 0.0
    ax = dict(_figures(bound, limit=3.0 * ARCMIN))['lost_motion'].axes[0]
    lines = {line.get_label(): line for line in ax.lines}
    apart = lines["joint_1 per window, at a new unit's play (not used)"]
    assert len(apart.get_xdata()) == 3
    assert len(lines['joint_1 observed per window'].get_xdata()) == len(res.features) - 3
