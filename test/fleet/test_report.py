"""The fleet report: one offline page, rendered by a real headless Chromium."""

import json
import re
import shutil
import subprocess

from cli_runs import run_cli as _run
import numpy as np
import pytest
from reducer_twin.analysis.simulate import simulate_bag, SimulationSpec
from reducer_twin.cli import main
from reducer_twin.fleet.report import COLOURS

CHROMIUM = shutil.which('chromium') or '/usr/bin/chromium'


def screenshot(page, png, profile, width=1200, height=1800):
    """Render a page with Debian's headless Chromium, offline, into a PNG."""
    subprocess.run([CHROMIUM, '--headless', '--no-sandbox', '--disable-gpu',
                    '--disable-background-networking', '--disable-component-update',
                    '--disable-sync', '--no-first-run', '--hide-scrollbars',
                    f'--user-data-dir={profile}', f'--window-size={width},{height}',
                    f'--screenshot={png}', page.as_uri()],
                   check=True, capture_output=True, timeout=120)


@pytest.fixture(scope='module')
def fleet_report(tmp_path_factory):
    root = tmp_path_factory.mktemp('fleet')
    bags = [str(simulate_bag(root / f'b{k}', SimulationSpec(
        hours=2000.0, start_hours=2000.0 * k, aging_factor=360_000.0, joints=2, rate_hz=250.0,
        seed=5, robot='r1', wear_rate_scales=(1.0, 20.0))).path) for k in range(2)]
    assert main(['analyze', *bags, '--store', str(root / 'f.db'), '--out',
                 str(root / 'out')]) == 0
    assert main(['replace', '--store', str(root / 'f.db'), '--robot', 'r1', '--joint',
                 'joint_1']) == 0
    assert main(['fleet', '--store', str(root / 'f.db'), '--report', str(root / 'report')]) == 0
    return root


def test_the_page_is_self_contained_with_the_ranked_table_rules_and_trends(fleet_report,
                                                                           capsys):
    page = (fleet_report / 'report' / 'index.html').read_text()
    assert not re.search(r'(src|href)="(?!data:)', page), 'the page must not load anything'
    assert page.count('data:image/png;base64,') == 1   # joint_2 (joint_1 is new: no data)
    code, out, _ = _run(['fleet', '--store', fleet_report / 'f.db', '--json'], capsys)
    rows = json.loads(out)['reducers']
    assert rows[0]['verdict'] in ('REPLACE', 'PLAN', 'OK')
    assert [r['verdict'] for r in rows[1:]] == ['NOT OBSERVED', 'RETIRED']
    # The model's simulator publishes what the twin reads as published: nothing to say.
    assert all(r['inputs'] == [] for r in rows) and 'Its inputs' not in page
    positions = [page.index(f'<b>{r["verdict"]}</b>') for r in rows]
    assert positions == sorted(positions)
    for rule in ('REPLACE', 'PLAN', 'OK', 'NOT OBSERVED'):
        assert f'>{rule}</span></dt>' in page


def test_headless_chromium_renders_the_report(fleet_report, tmp_path, capsys):
    png = tmp_path / 'fleet.png'
    screenshot(fleet_report / 'report' / 'index.html', png, tmp_path / 'profile')
    import matplotlib.image
    image = matplotlib.image.imread(png)
    assert image.shape[:2] == (1800, 1200)
    # Something was drawn: the verdict colours and the plots, not a blank page.
    colours = np.unique((image[..., :3] * 255).astype(np.uint8).reshape(-1, 3), axis=0)
    assert len(colours) > 50
    _, out, _ = _run(['fleet', '--store', fleet_report / 'f.db', '--json'], capsys)
    first = json.loads(out)['reducers'][0]['verdict']
    rgb = [int(COLOURS[first][k:k + 2], 16) for k in (1, 3, 5)]
    cell = np.all(np.abs(image[..., :3] * 255 - rgb) < 3, axis=-1)
    assert cell.sum() > 200, f'the {first} cell is not drawn'


def test_a_reducer_not_observed_gets_its_readings_and_no_estimate_curve(fleet_report):
    from reducer_twin.fleet.report import trend_figure
    from reducer_twin.fleet.store import FleetStore
    with FleetStore(fleet_report / 'f.db') as store:
        reducer = store.in_service('r1', 'joint_2')
        trend = store.trend(reducer.row_id)
    labels = {}
    for observed in (True, False):
        fig = trend_figure(trend, 'r1 / joint_2', reducer.lost_motion_limit_rad, observed)
        labels[observed] = [[a.get_label() for a in (*ax.lines, *ax.collections)]
                            for ax in fig.axes]
    assert 'estimate' in labels[True][0] and 'P50' in labels[True][1]
    lm, life = labels[False]
    assert 'observed per window' in lm and 'estimate' not in lm
    assert 'P50' not in life and 'P10–P90' not in life
    assert 'not observed: no estimate' in lm and 'not observed: no estimate' in life
