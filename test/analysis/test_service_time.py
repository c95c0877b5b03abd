"""
A used reducer's service time (the robot's hour meter) in ``reducer-twin analyze --config``.

A recording of 150 h of a robot whose reducers are half-way through lives the model does
not predict (the independent generator draws them whatever the duty): without the
service time the twin cannot tell a unit's rate from so short a stretch and says so; with
it (``service_time_s`` per joint) the rate is the unit's own and every joint's remaining
life comes closer to the truth. The calibration over many truths is
``bench/bench_service_time.py``'s.
"""

import json
import math

from bench_scripts import load
from cli_runs import analyze_process

gen = load('independent_generator')


def test_the_service_time_resolves_a_used_units_rate_and_brings_its_life_to_the_truth(
        tmp_path):
    spec = gen.Spec(seed=4, kinds=('base', 'shoulder', 'forearm'), hours=150.0,
                    aging_factor=3600.0, start_fraction=0.5)
    truth = gen.generate_bag(spec, tmp_path / 'bag')
    plain = tmp_path / 'plain.yaml'
    plain.write_text('twin:\n  aging_factor: 3600.0\n')
    served = tmp_path / 'served.yaml'
    served.write_text('twin:\n  aging_factor: 3600.0\nservice_time_s:\n' + ''.join(
        f'  {joint}: {t["start_hours"] * 3600.0!r}\n' for joint, t in truth['joints'].items()))
    runs = {}
    for name, config in (('plain', plain), ('served', served)):
        done = analyze_process(tmp_path / 'bag', tmp_path / name, '--config', config)
        assert done.returncode == 0 and 'Traceback' not in done.stderr, done.stderr[-500:]
        runs[name] = (json.loads(done.stdout)['joints'], done.stderr)
    # Without: the short stretch leaves some unit's rate unresolved, and it is said.
    assert not all(j['rate_resolved'] for j in runs['plain'][0].values())
    assert "this unit's own wear rate is not yet resolved" in runs['plain'][1]
    assert 'not yet resolved' not in runs['served'][1]
    # What was taken is in --json; a time in hours written as seconds is refused, and said.
    for joint, t in truth['joints'].items():
        service = runs['served'][0][joint]['service']
        assert service['taken'] and abs(service['hours'] - t['start_hours']) < 1e-6
    assert all(j['service'] is None for j in runs['plain'][0].values())
    hours = tmp_path / 'hours.yaml'
    hours.write_text('twin:\n  aging_factor: 3600.0\nservice_time_s:\n'
                     f'  joint_1: {truth["joints"]["joint_1"]["start_hours"]!r}\n')
    done = analyze_process(tmp_path / 'bag', tmp_path / 'hours', '--config', hours)
    assert done.returncode == 0, done.stderr[-500:]
    assert not json.loads(done.stdout)['joints']['joint_1']['service']['taken']
    assert [line for line in done.stderr.splitlines() if 'joint_1: service time' in line
            and 'not taken' in line and 'service_time_s is in seconds' in line]
    for joint, t in truth['joints'].items():
        true_life = t['remaining_life_end_h']
        off = {name: abs(math.log(joints[joint]['rul_p50_h'] / true_life))
               for name, (joints, _) in runs.items()}
        assert runs['served'][0][joint]['rate_resolved']
        assert off['served'] < off['plain'], (joint, true_life, off)
