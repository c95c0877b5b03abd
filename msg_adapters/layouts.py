"""
Labelled layouts of the twin's derived topics (std_msgs/Float64MultiArray).

Every derived value travels as a ``Float64MultiArray`` whose layout names
its fields, so a viewer (Foxglove, PlotJuggler) shows them by name and a
reader can check it got what it expects. Single records use one dimension
labelled with the comma-joined field names; batches use two dimensions,
``samples`` then the fields. Field names carry their unit, SI throughout.

This module is pure Python (no ROS import): the live nodes wrap the values
into ``std_msgs/msg/Float64MultiArray`` with :mod:`reducer_twin.msg_adapters.ros`, and
the offline analysis encodes the same layout to CDR bytes.
"""

from dataclasses import dataclass

from reducer_twin.core.errors import InvalidInput


@dataclass(frozen=True)
class Layout:
    """
    A named list of fields.

    Attributes
    ----------
    name : str
        Layout name, also the suffix of the topic that carries it.
    fields : tuple of str
        Field names, unit-suffixed.
    batch : bool
        True when a message carries many samples (2-D layout).

    """

    name: str
    fields: tuple
    batch: bool = False

    @property
    def label(self):
        """Return the dimension label: field names joined by commas."""
        return ','.join(self.fields)


TE_BATCH = Layout('te', ('stamp_s', 'output_angle_rad', 'te_rad', 'torque_nm'), batch=True)
"""Transmission error samples of one joint."""

PAIRED_SAMPLES = Layout('encoder_pairs', ('stamp_s', 'motor_angle_rad', 'link_angle_rad',
                                          'effort_nm', 'link_velocity_rad_s'), batch=True)
"""Validated, time-aligned motor/link samples of one joint."""

TE_FEATURES = Layout('te_features', (
    'window_start_s', 'window_end_s', 'samples', 'te_max_rad', 'te_min_rad', 'te_pp_rad',
    'te_mean_rad', 'loaded_mean_te_rad', 'lost_motion_rad', 'lost_motion_std_rad',
    'wear_fit_m', 'wear_fit_std_m', 'order1_rad', 'order2_rad', 'order_zc_rad',
    'order_zp_rad', 'time_offset_s', 'duration_s', 'exposure_s', 'archard_increment_m',
    'mean_abs_torque_nm', 'mean_abs_speed_rad_s', 'cubic_mean_torque_nm',
    'mean_speed_rad_s', 'max_abs_torque_nm', 'soft_zone_shortfall_rad', 'soft_zone_width_rad'))
"""
Per-window TE features and duty of one joint (paper Table 5 style); ``lost_motion_rad`` is
the play the loaded flanks give, the catalogue's lost motion ``soft_zone_shortfall_rad`` less
but not below ``soft_zone_width_rad``, the width those flanks' comparison gives at the test
torque (both 0 unless a soft zone reaching beyond the test torque is said). A negative
``soft_zone_shortfall_rad``: loads that never leave a soft zone, the flanks' reading below
the width their bins give at the test torque (``soft_zone_width_rad``, less the windup), the
lost motion given that much more but not above that width.
"""

WEAR_ESTIMATE = Layout('wear', (
    'stamp_s', 'wear_m', 'wear_std_m', 'rate_scale', 'rate_scale_std', 'log_rate_scale',
    'var_wear_m2', 'cov_wear_log_rate_m', 'var_log_rate', 'duty_rate_m_per_s',
    'lost_motion_rad', 'lost_motion_obs_rad', 'exposure_s', 'updates', 'rejected',
    'baseline_m', 'var_baseline_m2', 'cov_wear_baseline_m2', 'cov_log_rate_baseline_m',
    'lost_motion_std_rad', 'lost_motion_new_rad', 'duty_rate_rel_std', 'log_rate_drift_per_s',
    'archard_exposure_m', 'trend_probability', 'trend_new_rad', 'trend_growth_rad',
    'trend_exponent', 'var_trend_new_rad2', 'var_trend_growth_rad2', 'var_trend_exponent',
    'cov_trend_new_growth_rad2', 'cov_trend_new_exponent_rad', 'cov_trend_growth_exponent_rad',
    'soft_zone_shortfall_rad'))
"""
Estimate of one reducer: the wear model's state ``[w, ln s, b]`` (wear, rate scale, as-built
offset) and its covariance, the estimated lost motion now and when new, the duty rate with its
relative standard error, and the observed growth law ``z = β + k·(A/A_now)^g`` in the Archard
exposure ``A`` with its covariance and the probability that it holds. ``lost_motion_rad`` is
at the test torque: the play the loaded flanks give (``lost_motion_obs_rad``, the growth law)
less ``soft_zone_shortfall_rad`` where a soft zone reaches beyond the test torque (negative:
more, where the loads never leave one).
"""

REMAINING_LIFE = Layout('remaining_life', (
    'stamp_s', 'p10_s', 'p50_s', 'p90_s', 'mean_s', 'p10_censored', 'p50_censored',
    'p90_censored', 'censored_fraction', 'horizon_s', 'event_state', 'threshold_met',
    'catalogue_life_s', 'lost_motion_rad', 'lost_motion_limit_rad'))
"""Remaining operating life of one reducer (percentiles of operating seconds)."""

GROUND_TRUTH = Layout('ground_truth', (
    'stamp_s', 'wear_m', 'lost_motion_rad', 'exposure_s', 'wear_rate_scale', 'aging_factor',
    'limit_time_s', 'true_rul_s'))
"""Simulator truth of one joint (not available on a real robot)."""

LAYOUTS = {layout.name: layout for layout in
           (TE_BATCH, PAIRED_SAMPLES, TE_FEATURES, WEAR_ESTIMATE, REMAINING_LIFE, GROUND_TRUTH)}


def record_values(layout, record):
    """
    Order the values of a record by the layout's fields.

    Parameters
    ----------
    layout : Layout
        Target layout (single record).
    record : mapping
        Field name to value; missing fields are an error.

    Returns
    -------
    list of float
        Values in field order.

    Raises
    ------
    InvalidInput
        If a field is missing.

    """
    missing = [f for f in layout.fields if f not in record]
    if missing:
        raise InvalidInput(f'{layout.name} record lacks fields {missing}')
    return [float(record[f]) for f in layout.fields]


def parse_values(layout, labels, data):
    """
    Check a received layout and return its content by field name.

    Parameters
    ----------
    layout : Layout
        Expected layout.
    labels : sequence of (str, int)
        ``(label, size)`` of each dimension as received.
    data : sequence of float
        Flat data.

    Returns
    -------
    dict
        Field name to float (single record) or to a list of floats (batch).

    Raises
    ------
    InvalidInput
        If the labels or sizes do not match the layout.

    """
    n_fields = len(layout.fields)
    field_label = labels[-1][0] if labels else ''
    if field_label != layout.label:
        raise InvalidInput(f'expected layout {layout.name!r} with fields {layout.label!r}, '
                           f'got {field_label!r}')
    if layout.batch:
        if len(labels) != 2 or labels[1][1] != n_fields or len(data) != labels[0][1] * n_fields:
            raise InvalidInput(f'{layout.name}: batch of {labels} does not hold {len(data)} '
                               f'values of {n_fields} fields')
        rows = labels[0][1]
        return {f: [data[r * n_fields + k] for r in range(rows)]
                for k, f in enumerate(layout.fields)}
    if len(data) != n_fields:
        raise InvalidInput(f'{layout.name}: expected {n_fields} values, got {len(data)}')
    return dict(zip(layout.fields, (float(x) for x in data)))
