"""
The fleet report: one self-contained HTML page for the maintenance planner.

The page holds the ranked verdict table (coloured by verdict, with the rules that give
them), then per reducer in service its lost-motion trend (observed per window, the
estimate, the limit) and its remaining-life trend (P50 with the P10–P90 band, the limit
at zero, negative once past it) over operating hours across all its bags, bag starts
marked. Plots are PNGs inlined as data URIs: the page needs no network and no other
file. :func:`verdict_table` also serves the single-bag report.
"""

import base64
import html
import io
import math
from pathlib import Path

import numpy as np
from reducer_twin.core.units import ARCMIN, HOUR

COLOURS = {'REPLACE': '#f4b6b6', 'PLAN': '#f9dc9c', 'WATCH': '#c9dcf2', 'OK': '#bfe3bf',
           'NOT OBSERVED': '#d9d9d9', 'RETIRED': '#eeeeee'}
"""Background of each verdict's cells."""

STYLE = ('body{font-family:sans-serif;margin:1.5em;max-width:1100px}'
         'table{border-collapse:collapse;margin:0.5em 0}'
         'td,th{border:1px solid #bbb;padding:3px 7px;text-align:right;font-size:13px;'
         'white-space:nowrap}td.rule{white-space:normal;min-width:240px;font-size:12px}'
         'td.t,th.t{text-align:left}img{max-width:100%}dt{font-weight:bold}'
         'dd{margin:0 0 0.3em 1.5em}.rule{font-size:12px;color:#333}')
"""The pages' style sheet (inline)."""


def _fmt(value, spec):
    return '–' if value is None or not math.isfinite(value) else format(value, spec)


def verdict_table(rows, with_robot=True):
    """
    Return the verdict table as HTML.

    Parameters
    ----------
    rows : list of dict
        Rows of :func:`~reducer_twin.fleet.verdict.fleet_row`, ranked.
    with_robot : bool
        Include robot, bags and last-seen columns (the fleet page).

    Returns
    -------
    str
        ``<table>`` HTML.

    """
    head = (['robot'] if with_robot else []) + ['joint'] + (
        ['bags', 'last seen (UTC)'] if with_robot else []) + [
        'hours observed', 'wear (µm)', 'lost motion / limit (arcmin)',
        'RUL P10 / P50 / P90 (h)', 'verdict', 'why']
    out = ['<table><tr>' + ''.join(
        f'<th class="t">{html.escape(h)}</th>' if h in ('robot', 'joint', 'verdict', 'why')
        else f'<th>{html.escape(h)}</th>' for h in head) + '</tr>']
    for r in rows:
        wear = '–' if r['wear_um'] is None else \
            f'{r["wear_um"]:.2f} ± {_fmt(r["wear_std_um"], ".2f")}'
        lm = f'{_fmt(r["lost_motion_arcmin"], ".2f")} / ' \
             f'{_fmt(r["lost_motion_limit_arcmin"], ".2f")}'
        rul = ' / '.join(_fmt(r[k], ',.0f') for k in ('rul_p10_h', 'rul_p50_h', 'rul_p90_h'))
        if r.get('rul_censored'):
            rul += ' (beyond horizon)'
        colour = COLOURS.get(r['verdict'], '#ffffff')
        cells = ([f'<td class="t">{html.escape(r["robot"])}</td>'] if with_robot else []) + [
            f'<td class="t">{html.escape(r["joint"])}</td>'] + (
            [f'<td>{r["bags"]}{" + live" if r.get("live_segments") else ""}</td>',
             f'<td>{html.escape((r["last_seen"] or "–")[:16].replace("T", " "))}</td>']
            if with_robot else []) + [
            f'<td>{_fmt(r["hours_observed"], ",.0f")}</td>', f'<td>{wear}</td>',
            f'<td>{lm}</td>', f'<td>{rul}</td>',
            f'<td class="t" style="background:{colour}"><b>{html.escape(r["verdict"])}</b></td>',
            f'<td class="t rule">{html.escape(r["reason"])}</td>']
        out.append(f'<tr style="background:{colour}40">' + ''.join(cells) + '</tr>')
    out.append('</table>')
    return ''.join(out)


def rules_html():
    """Return the verdict rules as an HTML definition list."""
    from reducer_twin.fleet.verdict import RULES
    return '<dl>' + ''.join(
        f'<dt><span style="background:{COLOURS[v]};padding:0 6px">{html.escape(v)}</span>'
        f'</dt><dd>{html.escape(rule)}</dd>' for v, rule in RULES) + '</dl>'


def _pyplot():
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    return plt


def _png(fig):
    plt = _pyplot()
    buffer = io.BytesIO()
    fig.savefig(buffer, format='png', dpi=90)
    plt.close(fig)
    return base64.b64encode(buffer.getvalue()).decode('ascii')


def life_axis_limits(p10, p50, p90, skip=None):
    """
    Y range of a remaining-life plot that the first windows' transients do not squash.

    The first ``skip`` windows (default a tenth of them, at least 3: the filter's start
    from the prior) are left out of the range, and so are non-finite values and the top
    5 % (censored draws at the horizon); zero (the limit) is always shown.

    Returns
    -------
    tuple of float or None
        ``(bottom, top)`` [h], None when nothing is left to show.

    """
    if skip is None:
        skip = max(3, len(p50) // 10)
    values = np.concatenate([np.asarray(a, float)[skip:] for a in (p10, p50, p90)])
    values = values[np.isfinite(values)]
    if not values.size:
        return None
    lo, hi = min(0.0, float(np.percentile(values, 1))), float(np.percentile(values, 95))
    span = max(hi - lo, 1.0)
    return lo - 0.05 * span, hi + 0.1 * span


def trend_figure(trend, title, limit_rad, observed=True):
    """
    Draw a reducer's lost-motion and remaining-life trends across its bags.

    Parameters
    ----------
    trend : Trend
        From :meth:`~reducer_twin.fleet.store.FleetStore.trend`.
    title : str
        Robot and joint.
    limit_rad : float
        Lost-motion limit [rad].
    observed : bool
        Whether any lost motion was used: without one the estimate is the prior's
        alone, and only the windows' readings are drawn (never a curve beside NOT
        OBSERVED: on a heavy duty the model's rate alone reaches a remaining life of 0 h).

    Returns
    -------
    matplotlib.figure.Figure
        Two panels side by side.

    """
    from reducer_twin.msg_adapters.layouts import REMAINING_LIFE, TE_FEATURES, WEAR_ESTIMATE
    plt = _pyplot()

    def col(array, layout, name):
        return array[:, layout.fields.index(name)] if len(array) else np.zeros(0)

    fig, (ax_lm, ax_life) = plt.subplots(1, 2, figsize=(11, 3.4))
    hours = col(trend.wear, WEAR_ESTIMATE, 'exposure_s') / HOUR
    window_hours = np.cumsum(col(trend.features, TE_FEATURES, 'exposure_s')) / HOUR
    ax_lm.plot(window_hours, col(trend.features, TE_FEATURES, 'lost_motion_rad') / ARCMIN,
               '.', ms=3, alpha=0.5, label='observed per window')
    if observed:
        ax_lm.plot(hours, col(trend.wear, WEAR_ESTIMATE, 'lost_motion_rad') / ARCMIN,
                   label='estimate')
    if limit_rad:
        ax_lm.axhline(limit_rad / ARCMIN, color='C3', lw=1.2, ls='--', label='limit')
    ax_lm.set_ylabel('lost motion (arcmin)')
    p10, p50, p90 = (col(trend.life, REMAINING_LIFE, k) / HOUR
                     for k in ('p10_s', 'p50_s', 'p90_s'))
    if observed:
        ax_life.fill_between(hours, p10, p90, alpha=0.25, label='P10–P90')
        ax_life.plot(hours, p50, label='P50')
        limits = life_axis_limits(p10, p50, p90)
        if limits:
            ax_life.set_ylim(*limits)
    else:
        for ax in (ax_lm, ax_life):
            ax.plot([], [], ' ', label='not observed: no estimate')
    ax_life.axhline(0.0, color='C3', lw=1.2, ls='--', label='limit reached')
    ax_life.set_ylabel('remaining life (h)')
    for ax in (ax_lm, ax_life):
        for start in trend.bag_starts_h[1:]:
            ax.axvline(start, color='0.6', lw=0.6, ls=':')
        ax.set_xlabel('operating hours (dotted: a new bag or live session)')
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc='upper left', bbox_to_anchor=(1.0, 1.0))
    fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    return fig


def write_fleet_report(store, rows, out_dir):
    """
    Write the fleet report's ``index.html`` (self-contained) into ``out_dir``.

    Parameters
    ----------
    store : FleetStore
        The open store.
    rows : list of dict
        Ranked rows of the fleet view.
    out_dir : str or os.PathLike
        Directory (created if missing).

    Returns
    -------
    pathlib.Path
        The page.

    Raises
    ------
    InvalidParameter
        If the directory holds files that are not a previous report of reducer-twin.
    BagError
        If the directory cannot be written (``DiskFull`` when the disk is full).

    """
    from reducer_twin.analysis.report import GENERATOR
    from reducer_twin.fleet.store import utc_now
    by_key = {}
    for reducer in store.reducers():
        if reducer.in_service:
            by_key[reducer.key] = reducer
    sections = []
    for row in rows:
        reducer = by_key.get((row['robot'], row['joint']))
        if reducer is None or row['verdict'] == 'RETIRED' or not (
                reducer.bags or reducer.live_segments):
            continue
        title = f'{row["robot"]} / {row["joint"]}: {row["verdict"]}'
        image = _png(trend_figure(store.trend(reducer.row_id), title,
                                  reducer.lost_motion_limit_rad,
                                  observed=row['verdict'] != 'NOT OBSERVED'))
        said = ''.join(f'<li>{html.escape(line)}</li>' for line in row.get('inputs') or ())
        said = f'<p class="rule">Its inputs, as the latest analysis read them:</p><ul ' \
               f'class="rule">{said}</ul>' if said else ''
        sections.append(f'<h3>{html.escape(title)}</h3><p class="rule">'
                        f'{html.escape(row["reason"])}</p>{said}<img alt="{html.escape(title)}" '
                        f'src="data:image/png;base64,{image}">')
    counts = {}
    for row in rows:
        counts[row['verdict']] = counts.get(row['verdict'], 0) + 1
    tally = ', '.join(f'{n} {v}' for v, n in counts.items()) or 'no reducer'
    page = '\n'.join([
        '<!DOCTYPE html>', f'<html lang="en"><head><meta charset="utf-8">{GENERATOR}',
        '<title>reducer_twin fleet report</title>', f'<style>{STYLE}</style></head><body>',
        '<h1>Fleet report</h1>',
        f'<p>Store <code>{html.escape(str(store.path))}</code>, written {utc_now()}: '
        f'{len(rows)} reducer(s), {html.escape(tally)}. Most urgent first, ranked by the '
        'remaining life P10 (operating hours).</p>',
        verdict_table(rows), '<h2>Rules</h2>', rules_html(),
        '<h2>Trends across bags</h2>', ''.join(sections) or '<p>No reducer observed yet.</p>',
        '</body></html>', ''])
    from reducer_twin.io.outputs import OutputDir
    from reducer_twin.analysis.report import foreign_report_entries
    data = page.encode('utf-8')
    out = Path(out_dir)
    # Whole or not at all, and only into an empty directory or over a previous report.
    with OutputDir(out, foreign_report_entries, 'fleet report', '--report', overwrite=True,
                   needed=len(data), replace_note='a report written by reducer-twin') as tmp:
        (tmp / 'index.html').write_bytes(data)
    return out / 'index.html'
