"""
Bags into a reducer's history: ``reducer-twin analyze BAG... --store PATH``.

Each bag belongs to a robot (``--robot``, else its ``custom_data``
``reducer_twin.robot``, else ``twin.robot`` of ``--config``); each of its joints is a
reducer, the one in service on that robot. Per robot the bags form a *chain* in time
order (by the first JointState log time, whatever order they were given in): each bag
continues every reducer from where its previous bag, or the store, left the estimator.
Chains are independent, so they run in parallel (``--jobs`` processes, or Ray tasks);
within a chain the bags follow one another.

Before anything is analysed the plan decides per bag and joint: a bag whose fingerprint
is already in the reducer's history is skipped (never counted twice); a bag recorded
before the reducer's installation belongs to the reducer it replaced and is skipped for
that joint; a bag that starts before the end of the stored history is refused, unless
``--rebuild`` drops the history of the robot's reducers in service and analyses their
stored bags again together with the new ones. The results are written by this process
alone, one transaction per bag; a chain stops at its first failed bag so that no
reducer's history has a hole.
"""

import contextlib
from dataclasses import dataclass, field
import hashlib
import os
from pathlib import Path
import socket
import sys
import tempfile

from reducer_twin.analysis.stages import NEW_REDUCER
from reducer_twin.core.errors import BagError, InvalidParameter, ReducerTwinError
from reducer_twin.fleet.store import FleetStore, iso_from_ns, Segment, StoreError
from reducer_twin.io.mcap_reader import ReadWarning

FINGERPRINT_BYTES = 1 << 20
"""Bytes read from each end of every storage file for a bag's fingerprint."""


class BagSkipped(ReducerTwinError):
    """A bag that needs no analysis (already in the store); not an error."""


class BagRefused(ReducerTwinError):
    """A bag the store's history cannot take (older than what is stored)."""


@dataclass
class BagInfo:
    """
    What the plan knows of one bag before analysing it.

    Attributes
    ----------
    path : str
        The bag as given (or as stored, for a rebuild).
    name : str
        Its output name.
    out : str
        Its derived bag directory.
    robot : str
        The robot it belongs to.
    fingerprint : str
        sha256 of its storage files' sizes and first and last MiB.
    first_ns : int
        Log time of its first JointState message [ns].
    joints : tuple of str
        The joints the analysis will find in it.

    """

    path: str
    name: str
    out: str
    robot: str
    fingerprint: str
    first_ns: int
    joints: tuple


@dataclass
class ChainItem:
    """One bag of a robot's chain, and the reducers it is analysed for."""

    info: BagInfo
    joints: dict
    """Joint -> the reducer row's revision the write expects (None: new reducer)."""
    forget: tuple = ()
    """Reducer ids whose history this bag's write drops first (``--rebuild``)."""


@dataclass
class Done:
    """The outcome of one chain item: a BagResult or an error, and who analysed it."""

    item: ChainItem
    result: object
    worker: dict = field(default_factory=dict)


def fingerprint(bag):
    """
    Identify a bag by its content, wherever it lies.

    Parameters
    ----------
    bag : Bag
        An opened bag.

    Returns
    -------
    str
        Hex sha256 of every storage file's size, first and last
        :data:`FINGERPRINT_BYTES`.

    """
    digest = hashlib.sha256()
    for path in bag.files:
        size = os.path.getsize(path)
        digest.update(size.to_bytes(8, 'little'))
        with open(path, 'rb') as handle:
            digest.update(handle.read(FINGERPRINT_BYTES))
            if size > FINGERPRINT_BYTES:
                handle.seek(max(FINGERPRINT_BYTES, size - FINGERPRINT_BYTES))
                digest.update(handle.read())
    return digest.hexdigest()


def config_robot(config_path):
    """Return ``twin.robot`` of a bringup YAML, or '' when it sets none."""
    if not config_path:
        return ''
    from reducer_twin.config import load_config_sources
    config, given = load_config_sources(config_path)
    return str(config['twin'].get('robot') or '') if 'twin.robot' in given else ''


def inspect_bag(path, name, out, settings, robot_flag='', robot_config=''):
    """
    Open a bag and find its robot, fingerprint, start and joints.

    Raises
    ------
    InvalidParameter
        If no robot is named anywhere.
    BagError
        If the bag cannot be read or has no encoder pairs.

    """
    from reducer_twin.io.bag import open_bag
    from reducer_twin.analysis.joints import plan_joints, robot_plans
    from reducer_twin.analysis.simulate import ROBOT_KEY
    with open_bag(path) as bag:
        robot = robot_flag or bag.metadata.get(ROBOT_KEY, '') or robot_config
        if not robot:
            raise InvalidParameter(
                f'{path}: no robot name for the fleet store: pass --robot NAME, or set '
                f"twin.robot in --config (the bag's custom_data has no {ROBOT_KEY})")
        plan = plan_joints(bag, settings)
        first = None
        batches = bag.iter_raw([plan.link_topic])
        try:
            for _, raw in batches:
                if len(raw):
                    first = int(raw.log_time_ns.min())
                    break
        finally:
            batches.close()
        if first is None:
            raise BagError(f'{path}: no JointState message on {plan.link_topic}')
        # A recording of several robots (arms): the joints of each, by namespace.
        joints = tuple(j for p in robot_plans(bag, plan, settings) for j in p.joints)
        return BagInfo(str(path), name, str(out), robot, fingerprint(bag), first, joints)


# --------------------------------------------------------------------------- planning


def plan_chains(store, infos, settings, rebuild=False, scratch=None):
    """
    Decide, per robot, which bags to analyse for which reducers, in time order.

    Parameters
    ----------
    store : FleetStore
        The store (read only here).
    infos : list of BagInfo
        The bags given.
    settings : AnalysisSettings
        For opening stored bags on a rebuild.
    rebuild : bool
        Drop the history of the robots' reducers in service and analyse their stored
        bags again with the given ones.
    scratch : str, optional
        Directory for the derived bags of stored bags analysed again.

    Returns
    -------
    chains : dict of str to list of ChainItem
        Per robot, the bags to analyse in order.
    outcomes : dict of str to Exception
        Bags not analysed (BagSkipped, BagRefused), by path.
    start : dict of str to dict
        Per robot, the stored state of each joint's reducer (the chain's start).

    Raises
    ------
    InvalidParameter
        If a rebuild needs a stored bag that no longer exists, or would drop a history
        watched live (its windows exist only in the store).

    """
    by_robot = {}
    for info in infos:
        by_robot.setdefault(info.robot, []).append(info)
    chains, outcomes, start = {}, {}, {}
    for robot, bags in by_robot.items():
        reducers = {r.joint: r for r in store.reducers() if r.robot == robot and r.in_service}
        forget = ()
        if rebuild:
            live = [r for r in reducers.values() if r.live_segments]
            if live:
                names = ', '.join(f'{robot}/{r.joint} ({r.live_segments})' for r in live)
                raise InvalidParameter(
                    f'--rebuild cannot analyse the history of robot {robot} again: live '
                    f'segments of a wear_estimator are part of it ({names}), and their '
                    'windows exist only in the store; a bag older than that history cannot '
                    'join it')
            forget = tuple(r.row_id for r in reducers.values() if r.bags)
            bags = bags + _stored_again(store, robot, bags, settings, scratch)
        bags = sorted(bags, key=lambda b: (b.first_ns, b.fingerprint))
        last = {j: (None if r.row_id in forget else r.last_ns) for j, r in reducers.items()}
        have = {j: (set() if r.row_id in forget else _fingerprints(store, r.row_id))
                for j, r in reducers.items()}
        revision = {j: r.revision + (1 if r.row_id in forget else 0) for j, r in reducers.items()}
        start[robot] = {j: _start_state(r) for j, r in reducers.items()
                        if r.row_id not in forget}
        seen, items = set(), []
        for info in bags:
            if info.fingerprint in seen:
                outcomes[info.path] = BagSkipped(f'{info.path}: the same bag as one given '
                                                 'before it: skipped')
                continue
            seen.add(info.fingerprint)
            decision = _decide(robot, info, reducers, last, have, revision)
            if isinstance(decision, Exception):
                outcomes[info.path] = decision
                continue
            for joint in decision:
                last[joint] = info.first_ns
                have.setdefault(joint, set()).add(info.fingerprint)
                # Each write adds one to the row's revision (a new row: 0, then 1).
                revision[joint] = 1 if revision.get(joint) is None else revision[joint] + 1
            items.append(ChainItem(info, decision, forget if not items else ()))
        if items:
            chains[robot] = items
    return chains, outcomes, start


def _start_state(reducer):
    """Where a stored reducer's analysis starts: its state; new if fitted by a replacement."""
    if reducer.state is None and reducer.installed_ns is not None:
        return NEW_REDUCER
    return reducer.state


def _decide(robot, info, reducers, last, have, revision):
    joints, notes = {}, []
    for joint in info.joints:
        r = reducers.get(joint)
        if info.fingerprint in have.get(joint, ()):
            notes.append(f'{joint} already has it')
            continue
        if r is not None and r.installed_ns is not None and info.first_ns < r.installed_ns:
            notes.append(f'{joint} was replaced at {iso_from_ns(r.installed_ns)}, after it '
                         'was recorded')
            continue
        if last.get(joint) is not None and info.first_ns <= last[joint]:
            remedy = ('pass --rebuild to analyse the history again with it' if r is None
                      or not r.live_segments else 'that history was watched live (a '
                      'wear_estimator with store), so it cannot be analysed again')
            return BagRefused(
                f'{info.path}: starts at {iso_from_ns(info.first_ns)}, before the end of the '
                f'stored history of {robot}/{joint} ({iso_from_ns(last[joint])}); a bag '
                f'older than the history is refused: {remedy}')
        joints[joint] = revision.get(joint)
    if not joints:
        return BagSkipped(f'{info.path}: already in the fleet store for robot {robot} '
                          f'({"; ".join(notes)}): skipped, nothing counted twice')
    return joints


def _fingerprints(store, reducer_id):
    ids = store.segment_bags(reducer_id)
    return {b.fingerprint for b in store.bags_of_ids(ids)} if ids else set()


def _stored_again(store, robot, given, settings, scratch):
    """Return the BagInfo of the robot's stored bags not given, to analyse them again."""
    known = {b.fingerprint for b in given}
    out = []
    for row in store.bags_of(robot):
        if row.fingerprint in known:
            continue
        if not Path(row.path).exists():
            raise InvalidParameter(
                f'--rebuild needs the stored bag {row.path} of robot {robot} (analysed '
                f'{row.analysed_utc}), which does not exist any more; give its new path '
                'among the BAGs')
        name = f'stored_{row.row_id}'
        info = inspect_bag(row.path, name, str(Path(scratch) / name), settings, robot)
        out.append(info)
    return out


# --------------------------------------------------------------------------- running


def worker_identity(node=None):
    """Return ``{"node", "pid"}`` of this process (node: the host name unless given)."""
    return {'node': node or socket.gethostname(), 'pid': os.getpid()}


def analyse_in_chain(item, chain, settings, overwrite=False, stage_worker=False,
                     reader_process=False, node=None):
    """
    Analyse one bag of a chain, continuing the chain's reducers.

    Parameters
    ----------
    item : ChainItem
        The bag and the joints it is analysed for.
    chain : dict
        ``{"ok": bool, "why": str, "states": {joint: state}}``: where the chain is.
    settings : AnalysisSettings
        How to analyse.
    overwrite, stage_worker, reader_process
        As for :func:`~reducer_twin.analysis.pipeline.analyze_bag`.
    node : str, optional
        Name of the node for the worker identity.

    Returns
    -------
    tuple
        ``(Done, chain)``: the outcome and where the chain is after it.

    """
    from reducer_twin.analysis.pipeline import analyze_bag
    if not chain['ok']:
        return Done(item, BagRefused(f'{item.info.path}: not analysed: {chain["why"]}'),
                    worker_identity(node)), chain
    states = dict(chain['states'])
    initial = {j: states[j] for j in item.joints if states.get(j) is not None}
    try:
        result = analyze_bag(item.info.path, item.info.out, settings, overwrite, stage_worker,
                             reader_process, initial_states=initial)
    except ReducerTwinError as err:
        why = f'the earlier bag {item.info.path} of robot {item.info.robot} failed ({err})'
        chain = {'ok': False, 'why': why, 'states': states}
        return Done(item, err, worker_identity(node)), chain
    for joint in item.joints:
        states[joint] = result.states.get(joint)
    return Done(item, result, worker_identity(node)), {'ok': True, 'why': '', 'states': states}


def run_local(chains, start, settings, overwrite, jobs, worker):
    """
    Run the chains here (``--jobs 1``) or in ``jobs`` forked processes, one chain each.

    Yields
    ------
    Done
        Per bag, in chain order within each chain.

    """
    if jobs == 1 or len(chains) == 1:
        for robot, items in chains.items():
            chain = {'ok': True, 'why': '', 'states': dict(start.get(robot, {}))}
            for item in items:
                stage = worker if worker is not None and worker.alive else worker is not None
                done, chain = analyse_in_chain(item, chain, settings, overwrite, stage,
                                               reader_process=worker is not None)
                yield done
        return
    import concurrent.futures
    from concurrent.futures.process import BrokenProcessPool
    from reducer_twin.analysis.forking import pool_broken, run_task, stopping_pool
    with stopping_pool(min(jobs, len(chains))) as pool:
        futures = {pool.submit(run_task, _run_chain, items, start.get(robot, {}), settings,
                               overwrite): items
                   for robot, items in chains.items()}
        for future in concurrent.futures.as_completed(futures):
            try:
                yield from future.result()
            except BrokenProcessPool:
                yield from (Done(item, pool_broken(item.info.path)) for item in futures[future])


def _run_chain(items, start, settings, overwrite):
    chain = {'ok': True, 'why': '', 'states': dict(start)}
    out = []
    for item in items:
        done, chain = analyse_in_chain(item, chain, settings, overwrite)
        out.append(done)
    return out


# --------------------------------------------------------------------------- storing


def segments_of(item, result, settings):
    """Build the store segments of one analysed bag (the joints it was analysed for)."""
    from reducer_twin.msg_adapters.layouts import REMAINING_LIFE, TE_FEATURES, WEAR_ESTIMATE
    import numpy as np
    stamp = WEAR_ESTIMATE.fields.index('stamp_s')
    exposure = TE_FEATURES.fields.index('exposure_s')
    censored = REMAINING_LIFE.fields.index('p10_censored')
    out = []
    for joint, revision in item.joints.items():
        res = result.joints[joint]
        last_ns = item.info.first_ns
        if res.wear is not None and len(res.wear):
            last_ns = max(last_ns, int(round(float(res.wear[-1][stamp]) * 1e9)))
        summary = res.summary()
        summary['rul_censored'] = bool(len(res.life) and res.life[-1][censored] > 0)
        out.append(Segment(
            joint=joint, expected_revision=revision, state=result.states[joint],
            first_ns=item.info.first_ns, last_ns=last_ns, windows=len(res.features),
            exposure_s=float(np.sum(res.features[:, exposure])) if len(res.features) else 0.0,
            messages=res.messages, rejected=res.rejected, summary=summary,
            levels=list(res.levels), features=res.features, wear=res.wear, life=res.life,
            limit_rad=settings.life.lost_motion_limit, warn_s=settings.life.warn_s,
            error_s=settings.life.error_s))
    return out


def store_done(store, done, settings, engine):
    """
    Write one analysed bag into the store (one transaction).

    Returns
    -------
    object
        The BagResult, or the error that kept it out of the store.

    """
    result = done.result
    if isinstance(result, Exception):
        return result
    segments = segments_of(done.item, result, settings)
    for joint in result.joints:
        if joint not in done.item.joints:
            # Planned from the bag's first messages (the store's chain of each reducer is
            # fixed before the analysis): a joint that appears later is analysed, not stored.
            result.warnings.append(ReadWarning(
                done.item.info.path, None,
                f'{joint} first appears partway through the recording: analysed into the '
                f'derived bag, not stored in the fleet history of robot '
                f'{done.item.info.robot} (its joints are planned from the first messages); '
                'name it in twin.joints (--config) to store it'))
    worker = dict(done.worker, engine=engine)
    for seg in segments:
        seg.worker = worker
    last_ns = max([s.last_ns for s in segments] + [done.item.info.first_ns])
    try:
        store.write_bag(done.item.info.robot, done.item.info.fingerprint, done.item.info.path,
                        done.item.info.first_ns, last_ns, result.aging_factor,
                        result.messages, segments, forget=done.item.forget)
    except StoreError as err:
        return err
    return result


def analyze_into_store(args, settings, names, outs, worker):
    """
    Run ``analyze`` with ``--store`` and/or ``--engine ray``.

    Parameters
    ----------
    args : argparse.Namespace
        The analyze arguments (``bags``, ``store``, ``robot``, ``rebuild``, ``engine``,
        ``ray_address``, ``jobs``, ``overwrite``, ``config``).
    settings : AnalysisSettings
        How to analyse.
    names, outs : list of str
        Output name and derived bag directory of each given bag.
    worker : WorkerBacks or None
        The stage worker of a one-process run.

    Returns
    -------
    results : dict of str to object
        Per given bag: BagResult, BagSkipped or an error.
    workers : dict of str to dict
        Per analysed bag: ``{"node", "pid"}``.

    """
    if args.store is None:
        return _without_store(args, settings, names, outs)
    store = FleetStore(args.store, create=True)
    try:
        store.lock_for_writing(notify=lambda text: sys.stderr.write(f'NOTE: {text}\n'))
        robot_config = config_robot(args.config)
        infos, results = [], {}
        for bag, name, out in zip(args.bags, names, outs):
            try:
                infos.append(inspect_bag(bag, name, out, settings, args.robot or '',
                                         robot_config))
            except InvalidParameter:
                raise
            except ReducerTwinError as err:
                results[bag] = err
        with tempfile.TemporaryDirectory(prefix='reducer-twin-rebuild-') as scratch:
            chains, outcomes, start = plan_chains(store, infos, settings, args.rebuild,
                                                  scratch)
            results.update(outcomes)
            workers = {}
            broken = {}
            # Closed here, also when stopped: the engine's workers (Ray's processes)
            # end with the loop, not when the interpreter collects it.
            with contextlib.closing(_engine(args, chains, start, settings,
                                            worker)) as runs:
                for done in runs:
                    info = done.item.info
                    if info.robot in broken and not isinstance(done.result, Exception):
                        outcome = BagRefused(f'{info.path}: not stored: {broken[info.robot]}')
                    else:
                        outcome = store_done(store, done, settings, args.engine)
                    if isinstance(outcome, Exception) and info.robot not in broken:
                        broken[info.robot] = f'the earlier bag {info.path} was not stored'
                    if info.name.startswith('stored_'):
                        if isinstance(outcome, Exception):
                            sys.stderr.write(f'ERROR: --rebuild: stored bag {outcome}\n')
                        continue
                    results[info.path] = outcome
                    workers[info.path] = done.worker
    finally:
        store.close()
    return results, workers


def _engine(args, chains, start, settings, worker):
    if args.engine == 'ray':
        from reducer_twin.fleet.ray_engine import run_ray
        return run_ray(chains, start, settings, args.overwrite, args.jobs, args.ray_address)
    return run_local(chains, start, settings, args.overwrite, args.jobs, worker)


def _without_store(args, settings, names, outs):
    """``--engine ray`` without a store: every bag is a chain of its own, a new reducer."""
    chains = {}
    for k, (bag, name, out) in enumerate(zip(args.bags, names, outs)):
        info = BagInfo(str(bag), name, str(out), f'bag {k}', '', 0, ())
        chains[f'bag {k}'] = [ChainItem(info, {})]
    results, workers = {}, {}
    with contextlib.closing(_engine(args, chains, {}, settings, None)) as runs:
        for done in runs:
            results[done.item.info.path] = done.result
            workers[done.item.info.path] = done.worker
    return results, workers
