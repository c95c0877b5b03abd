"""``reducer-twin model``: what-if query of the reducer model at a wear and torque."""

import numpy as np

from reducer_twin.commands.common import add_params_option, console, load_params, print_json
from reducer_twin.core.contact import contact_summary, solve_mesh
from reducer_twin.core.errors import InvalidParameter, out_of_range
from reducer_twin.core.transmission_error import hysteresis, lost_motion, mean_te, mesh_te_ripple
from reducer_twin.core.transmission_error import series_stiffness
from reducer_twin.core.units import ARCMIN, ARCSEC, HOUR, UM
from reducer_twin.core.wear import wear_rate

MAX_WEAR_UM = 500.0


def add_parser(sub):
    """Register the subcommand."""
    p = sub.add_parser('model', help='TE, lost motion and contact at a given wear and torque',
                       description=__doc__)
    p.add_argument('--wear-um', type=float, required=True,
                   help=f'combined wear of disc and pins [um], 0 .. {MAX_WEAR_UM:g}')
    p.add_argument('--torque-nm', type=float, required=True,
                   help='output torque [N*m], |T| up to 5 x rated')
    p.add_argument('--speed-rpm', type=float, default=None,
                   help='output speed for the wear rate [rpm] (default: rated)')
    p.add_argument('--json', action='store_true', help='print one JSON object')
    add_params_option(p)
    p.set_defaults(run=run)


def evaluate(params, wear, torque, speed):
    """
    Evaluate the model at one operating point (SI in, mixed edge units out).

    Parameters
    ----------
    params : ReducerParams
        Reducer parameters.
    wear : float
        Combined wear [m].
    torque : float
        Output torque [N*m].
    speed : float
        Output speed [rad/s].

    Returns
    -------
    dict
        The JSON summary (units in the key names).

    """
    psi = np.linspace(0.0, 2.0 * np.pi / params.geometry.z_pins, 64, endpoint=False)
    mesh = solve_mesh(psi, torque, params, wear)
    c = contact_summary(mesh, params)
    k = int(np.argmax(c['peak_pressure']))
    lm = lost_motion(wear, params)
    return {
        'wear_um': wear / UM,
        'torque_nm': torque,
        'lost_motion_arcmin': lm / ARCMIN,
        'hysteresis_at_torque_arcmin': hysteresis(wear, torque, params) / ARCMIN,
        'mean_te_arcmin': mean_te(wear, torque, params) / ARCMIN,
        'mean_te_shift_vs_new_arcmin': (mean_te(0.0, torque, params)
                                        - mean_te(wear, torque, params)) / ARCMIN,
        'te_ripple_arcsec': mesh_te_ripple(wear, torque, params) / ARCSEC,
        'loaded_pins': float(c['loaded_pins'].mean()),
        'max_pin_force_n': float(c['max_force'].max()),
        'max_contact_pressure_pa': float(c['peak_pressure'][k]),
        'contact_half_width_m': float(c['half_width'][k]),
        'equivalent_radius_m': float(c['equivalent_radius'][k]),
        'series_stiffness_nm_per_arcmin': series_stiffness(params.geometry, params.rating)
        * ARCMIN,
        'wear_rate_um_per_1000h': float(wear_rate(torque, speed, wear, params)) * 1000 * HOUR
        / UM,
    }


def run(args):
    """Validate the query, evaluate the model and print it."""
    params = load_params(args)
    if not (0.0 <= args.wear_um <= MAX_WEAR_UM):
        raise InvalidParameter(out_of_range('--wear-um', args.wear_um, 'um',
                                            f'in [0, {MAX_WEAR_UM:g}]'))
    t_max = 5.0 * params.rating.rated_torque
    if not (abs(args.torque_nm) <= t_max):
        raise InvalidParameter(out_of_range('--torque-nm', args.torque_nm, 'N*m',
                                            f'in [-{t_max:g}, {t_max:g}] (5 x rated)'))
    speed = params.rating.rated_output_speed
    if args.speed_rpm is not None:
        if not (0.0 <= args.speed_rpm <= 1000.0):
            raise InvalidParameter(out_of_range('--speed-rpm', args.speed_rpm, 'rpm',
                                                'in [0, 1000]'))
        speed = args.speed_rpm * 2.0 * np.pi / 60.0
    result = evaluate(params, args.wear_um * UM, args.torque_nm, speed)
    if args.json:
        print_json(result)
        return 0
    from rich.table import Table
    t = Table(title=f'RV model at {args.wear_um:g} um wear, {args.torque_nm:g} N*m')
    t.add_column('quantity')
    t.add_column('value', justify='right')
    for key, value in result.items():
        t.add_row(key, f'{value:.6g}')
    console().print(t)
    return 0
