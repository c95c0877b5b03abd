"""
The analysis report: PNG plots and one self-contained HTML page per bag.

The page starts with the date, the input path and the verdict table of the fleet view
(:mod:`reducer_twin.fleet.verdict`: REPLACE / PLAN / WATCH / OK / NOT OBSERVED with the rule
that gave it). Plots (matplotlib, Agg backend, no display needed): TE over the output
angle (thinned to :data:`~reducer_twin.analysis.pipeline.REPORT_TE_POINTS` samples per
joint; the hysteresis the lost motion is read from), the lost-motion trend (observed
per window and the estimate, against the truth when the bag has it), the wear estimate
with its ±2σ band against the truth, and the remaining life P50 with its P10–P90 band
against the true remaining life, its range set without the first windows' transients.
Legends sit beside the axes. Edge units: arc minutes, µm, hours. The HTML page embeds
the PNGs (data URIs), so it can be mailed or archived alone; the PNG files sit beside it.
"""

import base64
import html
import io
import math
from pathlib import Path

import numpy as np
from reducer_twin.core.pipeline import taken_off
from reducer_twin.core.units import ARCMIN, HOUR, UM
from reducer_twin.io.outputs import OutputDir
from reducer_twin.msg_adapters.layouts import (
    GROUND_TRUTH, REMAINING_LIFE, TE_FEATURES, WEAR_ESTIMATE)

GENERATOR = '<meta name="generator" content="reducer-twin">'
"""The tag that marks an ``index.html`` as a report of reducer-twin."""

PLOTS = (('te_angle', 'Transmission error over the output angle'),
         ('lost_motion', 'Lost motion trend'),
         ('wear', 'Wear estimate'),
         ('remaining_life', 'Remaining life'))
"""File stems and titles of the plots, in page order."""


def _col(array, layout, name):
    return array[:, layout.fields.index(name)] if array is not None and len(array) else \
        np.zeros(0)


def _pyplot():
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    return plt


def _te_angle(ax, joint, res):
    te = res.te
    if not len(te):
        ax.text(0.5, 0.5, 'no TE samples', ha='center', transform=ax.transAxes)
        return
    angle = np.degrees(np.mod(te[:, 1], 2.0 * np.pi))
    loaded = te[:, 3] >= 0.0
    ax.plot(angle[loaded], te[loaded, 2] / ARCMIN, '.', ms=1.5, alpha=0.5, label='T >= 0')
    ax.plot(angle[~loaded], te[~loaded, 2] / ARCMIN, '.', ms=1.5, alpha=0.5, label='T < 0')
    ax.set_xlabel('output angle (deg, mod 360)')
    ax.set_ylabel('TE (arcmin)')
    ax.set_title(joint)
    ax.legend(fontsize=7, markerscale=6)


def _hours(res):
    """Exposure hours at the end of each window (cumulated duty exposure)."""
    return np.cumsum(_col(res.features, TE_FEATURES, 'exposure_s')) / HOUR


def _readings(ax, joint, res):
    """
    Plot the windows' lost-motion readings with their sd; return their line.

    A reading whose wear fit lies on the table's lower bound (no play beyond a new
    nominal unit's: censored, never used by the estimate) is drawn hollow, apart.
    """
    h = _hours(res)
    # At the test torque, as the estimate: the play less a soft zone's shortfall, if said,
    # not below the width at the test torque.
    play = _col(res.features, TE_FEATURES, 'lost_motion_rad')
    taken = taken_off(_col(res.features, TE_FEATURES, 'soft_zone_shortfall_rad'),
                      _col(res.features, TE_FEATURES, 'soft_zone_width_rad'), lambda: play)
    obs = (play - taken) / ARCMIN
    std = _col(res.features, TE_FEATURES, 'lost_motion_std_rad') / ARCMIN
    bound = _col(res.features, TE_FEATURES, 'wear_fit_m') <= 0.0
    used = ~bound
    line, = ax.plot(h[used], obs[used], '.', ms=3, alpha=0.5,
                    label=f'{joint} observed per window' if used.any() else '_readings')
    ax.errorbar(h, obs, yerr=std, fmt='none', ecolor=line.get_color(), alpha=0.15)
    if bound.any():
        ax.plot(h[bound], obs[bound], 'o', ms=4, mfc='none', color=line.get_color(),
                alpha=0.6, label=f"{joint} per window, at a new unit's play (not used)")
    return line


def _lost_motion(ax, joint, res, limit):
    line = _readings(ax, joint, res)
    wh = _col(res.wear, WEAR_ESTIMATE, 'exposure_s') / HOUR
    ax.plot(wh, _col(res.wear, WEAR_ESTIMATE, 'lost_motion_rad') / ARCMIN,
            color=line.get_color(), label=f'{joint} estimate')
    if res.truth is not None and len(res.truth):
        ax.plot(_col(res.truth, GROUND_TRUTH, 'exposure_s') / HOUR,
                _col(res.truth, GROUND_TRUTH, 'lost_motion_rad') / ARCMIN, '--',
                color=line.get_color(), label=f'{joint} truth')


def _wear(ax, joint, res):
    h = _col(res.wear, WEAR_ESTIMATE, 'exposure_s') / HOUR
    w = _col(res.wear, WEAR_ESTIMATE, 'wear_m') / UM
    s = _col(res.wear, WEAR_ESTIMATE, 'wear_std_m') / UM
    line, = ax.plot(h, w, label=f'{joint} estimate')
    # Wear is never negative (the estimator keeps it >= 0): the band stops at zero.
    ax.fill_between(h, np.maximum(w - 2 * s, 0.0), w + 2 * s, color=line.get_color(),
                    alpha=0.2, label=f'{joint} ±2σ')
    if res.truth is not None and len(res.truth):
        ax.plot(_col(res.truth, GROUND_TRUTH, 'exposure_s') / HOUR,
                _col(res.truth, GROUND_TRUTH, 'wear_m') / UM, '--', color=line.get_color(),
                label=f'{joint} truth')


def _life(ax, joint, res):
    h = _col(res.wear, WEAR_ESTIMATE, 'exposure_s') / HOUR
    p10, p50, p90 = (_col(res.life, REMAINING_LIFE, k) / HOUR for k in ('p10_s', 'p50_s',
                                                                        'p90_s'))
    line, = ax.plot(h, p50, label=f'{joint} P50')
    ax.fill_between(h, p10, p90, color=line.get_color(), alpha=0.2, label=f'{joint} P10–P90')
    if res.truth is not None and len(res.truth):
        ax.plot(_col(res.truth, GROUND_TRUTH, 'exposure_s') / HOUR,
                _col(res.truth, GROUND_TRUTH, 'true_rul_s') / HOUR, '--',
                color=line.get_color(), label=f'{joint} truth')


def wear_axis_limits(wear_um, std_um, skip=None):
    """
    Y range of a wear plot [µm] that the first windows' prior does not squash.

    The first ``skip`` windows (default a tenth of them, at least 3: a reducer met
    without state starts from a prior several µm wide) are left out, and so are
    non-finite values; zero is always shown.

    Returns
    -------
    tuple of float or None
        ``(bottom, top)`` [µm], None when nothing is left to show.

    """
    if skip is None:
        skip = max(3, len(wear_um) // 10)
    top = np.asarray(wear_um, float)[skip:] + 2.0 * np.asarray(std_um, float)[skip:]
    top = top[np.isfinite(top)]
    if not top.size:
        return None
    hi = max(float(top.max()), 1e-3)
    return -0.05 * hi, 1.1 * hi


def _wear_limits(ax, results):
    found = [wear_axis_limits(_col(r.wear, WEAR_ESTIMATE, 'wear_m') / UM,
                              _col(r.wear, WEAR_ESTIMATE, 'wear_std_m') / UM) for r in results]
    found = [f for f in found if f is not None]
    if found:
        ax.set_ylim(min(f[0] for f in found), max(f[1] for f in found))


def _life_limits(ax, results):
    """Y range of the remaining-life plot without the first windows' transients."""
    from reducer_twin.fleet.report import life_axis_limits
    found = [life_axis_limits(*(_col(r.life, REMAINING_LIFE, k) / HOUR
                                for k in ('p10_s', 'p50_s', 'p90_s'))) for r in results]
    found = [f for f in found if f is not None]
    if found:
        ax.set_ylim(min(f[0] for f in found), max(f[1] for f in found))
    ax.axhline(0.0, color='k', lw=0.8, ls=':')


def _figures(result, limit):
    """Yield ``(stem, figure)`` of every plot."""
    plt = _pyplot()
    joints = result.joints
    n = max(1, len(joints))
    # TE over the output angle shows the hysteresis the lost motion is read from; TE over
    # stream time told a maintainer nothing and is no longer drawn.
    fig, axes = plt.subplots(n, 1, figsize=(9, 2.8 * n), squeeze=False)
    for ax, (joint, res) in zip(axes[:, 0], joints.items()):
        _te_angle(ax, joint, res)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    yield 'te_angle', fig
    for stem, draw, ylabel in (
            ('lost_motion', _lost_motion, 'lost motion (arcmin); dotted: limit'),
            ('wear', _wear, 'combined wear (µm), band ±2σ'),
            ('remaining_life', _life, 'remaining life (h), band P10–P90')):
        fig, ax = plt.subplots(figsize=(10.5, 4.5))
        for joint, res in joints.items():
            if not res.observed:
                # Never a curve of the model's guess beside "NOT OBSERVED" in the table:
                # without a lost motion the estimate is the prior's alone (a remaining life
                # of 0 h from the model's rate at a heavy duty). Only the windows' readings.
                if stem == 'lost_motion':
                    _readings(ax, joint, res)
                ax.plot([], [], ' ', label=f'{joint}: not observed, no estimate')
            elif stem == 'lost_motion':
                draw(ax, joint, res, limit)
            else:
                draw(ax, joint, res)
        if stem == 'lost_motion':
            ax.axhline(limit / ARCMIN, color='k', lw=0.8, ls=':')
        elif not any(res.observed for res in joints.values()):
            ax.text(0.5, 0.5, 'no joint observed: no estimate', transform=ax.transAxes,
                    ha='center', va='center', color='0.4')
        ax.set_xlabel('operating hours (exposure)')
        ax.set_ylabel(ylabel)
        if stem == 'remaining_life':
            _life_limits(ax, [r for r in joints.values() if r.observed])
        elif stem == 'wear':
            _wear_limits(ax, [r for r in joints.values() if r.observed])
        ax.grid(alpha=0.3)
        # Outside the axes: a legend inside covered the curves and the axis label.
        ax.legend(fontsize=7, loc='upper left', bbox_to_anchor=(1.01, 1.0))
        fig.tight_layout()
        yield stem, fig


def _fmt(value, spec):
    return '–' if value is None or not math.isfinite(value) else format(value, spec)


def _table(result):
    head = ('joint', 'wear (µm)', 'true wear (µm)', 'lost motion (arcmin)',
            'RUL P10 / P50 / P90 (h)', 'true RUL (h)', 'health', 'windows', 'messages',
            'rejected')
    rows = []
    for joint, res in result.joints.items():
        s = res.summary()
        truth = res.truth[-1] if res.truth is not None and len(res.truth) else None
        true_wear = truth[GROUND_TRUTH.fields.index('wear_m')] / UM if truth is not None \
            else None
        true_rul = truth[GROUND_TRUTH.fields.index('true_rul_s')] / HOUR if truth is not None \
            else None
        rul = ' / '.join(_fmt(s[k], ',.0f') for k in ('rul_p10_h', 'rul_p50_h', 'rul_p90_h'))
        cells = (joint, f'{_fmt(s["wear_um"], ".3f")} ± {_fmt(s["wear_std_um"], ".3f")}',
                 _fmt(true_wear, '.3f'),
                 f'{_fmt(s["lost_motion_arcmin"], ".3f")} ± '
                 f'{_fmt(s["lost_motion_std_arcmin"], ".3f")}', rul,
                 _fmt(true_rul, ',.0f'), res.levels[-1] if res.levels else 'STALE',
                 str(len(res.features)), f'{s["messages"]:,}', str(s['rejected']))
        rows.append('<tr>' + ''.join(f'<td>{html.escape(c)}</td>' for c in cells) + '</tr>')
    return ('<table><tr>' + ''.join(f'<th>{html.escape(h)}</th>' for h in head) + '</tr>'
            + ''.join(rows) + '</table>')


def foreign_report_entries(path):
    """
    Return the entries of a directory that are not part of a report of reducer-twin.

    A report is ``index.html`` carrying the :data:`GENERATOR` tag and the PNGs of
    :data:`PLOTS`; anything else (another page, the user's own plot) is foreign.

    Parameters
    ----------
    path : str or os.PathLike
        A non-empty directory.

    Returns
    -------
    list of str
        Entry names that reducer-twin did not write.

    """
    path = Path(path)
    entries = sorted(p.name for p in path.iterdir())
    page = path / 'index.html'
    ours = False
    if page.is_file() and not page.is_symlink():
        try:
            with open(page, 'rb') as stream:
                ours = GENERATOR.encode() in stream.read(4096)
        except OSError:
            ours = False
    allowed = {'index.html'} | {f'{stem}.png' for stem, _ in PLOTS} if ours else set()
    return [name for name in entries if name not in allowed or not (path / name).is_file()
            or (path / name).is_symlink()]


def write_report(result, out_dir, limit=None, life=None, flag='--report'):
    """
    Write the plots and the HTML page of one analysed bag, whole or not at all.

    The directory must be new, empty or hold a previous report (which is replaced);
    the files are written into a temporary sibling and renamed into place.

    Parameters
    ----------
    result : BagResult
        Output of :func:`~reducer_twin.analysis.pipeline.analyze_bag`.
    out_dir : str or os.PathLike
        Directory for ``index.html`` and the PNGs (created if missing).
    limit : float, optional
        Lost-motion limit to draw [rad]; default the one of the remaining-life records.
    life : LifeConfig, optional
        Thresholds of the verdicts (default the defaults).
    flag : str
        Option name of the directory, for messages.

    Returns
    -------
    pathlib.Path
        The HTML page.

    Raises
    ------
    InvalidParameter
        If the directory holds files that are not a previous report.
    BagError
        If the directory cannot be written (``DiskFull`` when the disk is full).

    """
    out = Path(out_dir)
    if limit is None:
        limits = [r.life[-1][REMAINING_LIFE.fields.index('lost_motion_limit_rad')]
                  for r in result.joints.values() if r.life is not None and len(r.life)]
        limit = limits[0] if limits else 3.0 * ARCMIN
    files, images = {}, {}
    plt = _pyplot()
    for stem, fig in _figures(result, limit):
        buffer = io.BytesIO()
        fig.savefig(buffer, format='png', dpi=100)
        plt.close(fig)
        files[f'{stem}.png'] = buffer.getvalue()
        images[stem] = base64.b64encode(files[f'{stem}.png']).decode('ascii')
    files['index.html'] = _page(result, images, life).encode('utf-8')
    output = OutputDir(out, foreign_report_entries, 'report', flag, overwrite=True,
                       needed=sum(len(data) for data in files.values()),
                       replace_note='a report written by reducer-twin')
    with output as tmp:
        for name, data in files.items():
            (tmp / name).write_bytes(data)
    return out / 'index.html'


def _verdicts(result, life):
    """Return the verdict table of the fleet view, with the date, the input and the rules."""
    from reducer_twin.fleet.report import rules_html, verdict_table
    from reducer_twin.fleet.store import utc_now
    from reducer_twin.fleet.verdict import bag_rows
    return (f'<p>Analysed {utc_now()} from <code>{html.escape(str(result.bag.resolve()))}'
            '</code>.</p><h2>Verdicts</h2>' + verdict_table(bag_rows(result, life), False)
            + '<details><summary>Rules</summary>' + rules_html() + '</details>')


def _page(result, images, life=None):
    title = f'reducer_twin analysis of {result.bag.name}'
    notes = ''.join(f'<li>{html.escape(str(w))}</li>' for w in result.warnings)
    # An estimate that stands as of a window well before the recording's end says so.
    notes += ''.join(f'<li>{html.escape(joint)}: observed in part: {html.escape(res.partial)}'
                     '</li>' for joint, res in result.joints.items()
                     if res.observed and res.partial)
    sections = ''.join(
        f'<h2>{html.escape(t)}</h2><p><img alt="{html.escape(t)}" src="data:image/png;base64,'
        f'{images[stem]}"></p>' for stem, t in PLOTS if stem in images)
    topics = f'<code>{html.escape(result.plan.link_topic)}</code>'
    if result.plan.motor_topic:
        topics += f' and <code>{html.escape(result.plan.motor_topic)}</code>'
    parts = [
        '<!DOCTYPE html>',
        f'<html lang="en"><head><meta charset="utf-8">{GENERATOR}',
        f'<title>{html.escape(title)}</title>',
        '<style>body{font-family:sans-serif;margin:2em;max-width:1000px}',
        'table{border-collapse:collapse}',
        'td,th{border:1px solid #bbb;padding:3px 8px;text-align:right}',
        # The verdict table's text cells (the fleet view's classes): read left to right.
        'td.t,th.t{text-align:left}td.rule{min-width:240px;font-size:13px}',
        'img{max-width:100%}</style></head><body>',
        f'<h1>{html.escape(title)}</h1>',
        f'<p>Bag: <code>{html.escape(str(result.bag))}</code>; derived bag: '
        f'<code>{html.escape(str(result.out))}</code>; JointState {topics}; aging factor '
        f'{result.aging_factor:g}; {result.messages:,} messages in {result.seconds:.2f} s.</p>',
        _verdicts(result, life),
        '<h2>Details</h2>',
        _table(result),
        f'<h2>Warnings</h2><ul>{notes}</ul>' if notes else '',
        sections,
        '</body></html>',
        '']
    return '\n'.join(parts)
