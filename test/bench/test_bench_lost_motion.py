"""
``bench/bench_lost_motion.py``'s summary of the third generator's friction loop.

The third generator's truth is the catalogue's lost motion, at the middle of its Dahl
loop; a joint that meets its loads only on the loading branch reads a whole loop height
narrower. The summary prints each kind's signed error with that height added back, so
the benchmark itself shows how much of an error the loop explains.
"""

import math

from bench_scripts import load

load('independent_generator')   # the script imports both generators by name
load('third_generator')
blm = load('bench_lost_motion')


def joint(kind, truth, reported, loop):
    return {'kind': kind, 'truth': truth, 'reported': reported, 'window': math.nan,
            'observed': True, 'loop': loop}


def test_the_loop_summary_adds_each_joints_loop_height_back(capsys):
    runs = [{'joints': {'joint_1': joint('base', 1.28, 0.92, 0.36),
                        'joint_2': joint('shoulder', 1.00, 1.05, 0.10)}},
            {'joints': {'joint_1': joint('base', 1.13, 0.79, 0.34),
                        'joint_2': joint('shoulder', 2.00, 1.90, 0.20)}}]
    blm._by_loop(runs, 'reported')
    lines = capsys.readouterr().out.splitlines()
    base, shoulder = lines
    assert 'base' in base and 'H 0.34-0.36 arcmin' in base
    # Read at the loading branch: 28 and 30 % low, right once H is added back.
    assert 'signed median -29.1 %' in base and 'with H added  +0.0 %' in base
    assert 'mean absolute 29.1 ->  0.0 %' in base
    assert 'shoulder' in shoulder and 'with H added +10.0 %' in shoulder


def test_joints_without_a_loop_or_a_reading_are_left_out(capsys):
    runs = [{'joints': {'joint_1': joint('base', 1.0, math.nan, 0.3),
                        'joint_2': joint('forearm', 1.0, 0.9, None)}}]
    blm._by_loop(runs, 'reported')
    assert capsys.readouterr().out == ''
