"""
Which joints a recording holds: motor/link pairs found on its JointState topics.

:func:`plan_joints` finds, per robot (topic namespace), the joints whose link and motor
entries (one message with ``<joint>`` and ``<joint><motor_suffix>``, or two topics)
the twin can pair, by the ingestion node's rules or the configuration, and says why a
joint is not analysed (:class:`JointPlan`).
"""

from dataclasses import dataclass, replace

from reducer_twin.analysis.reading import warn
from reducer_twin.core.errors import BagError
from reducer_twin.io.bag import JOINT_STATE_TYPES
from reducer_twin.io.rosbag1 import SERIALIZATION as ROS1
from reducer_twin.msg_adapters.jointstate_cdr import MSGTYPE as JOINT_STATE


@dataclass(frozen=True)
class JointPlan:
    """
    Where the joints of a bag are.

    Attributes
    ----------
    link_topic : str
        JointState topic of the link side (and of the motor side when combined).
    motor_topic : str or None
        JointState topic of the motor side when split.
    joints : tuple of str
        Joint names.
    motor_names : tuple of str
        Name of each joint's motor entry (``<joint><suffix>`` combined, ``<joint>``
        split).
    others : tuple of tuple
        ``(link topic, joints, motor topic or None, motor entry names)`` of the other
        topics with motor/link pairs, which this plan leaves out (:meth:`not_analysed`;
        :func:`robot_plans` makes a plan of each).
    prefix : str
        Put before the topic's entry names (``<namespace>/``) when a recording holds
        several robots; ``joints`` and ``motor_names`` carry it.
    unpaired : tuple of str
        Entries of ``link_topic``'s first messages that pair with nothing (found
        without ``twin.joints``; :func:`say_unpaired`).

    """

    link_topic: str
    motor_topic: str
    joints: tuple
    motor_names: tuple
    others: tuple = ()
    prefix: str = ''
    unpaired: tuple = ()

    def not_analysed(self):
        """
        Joints of the bag's other paired topics, which this analysis leaves out.

        Returns
        -------
        dict of str to str
            ``<namespace>/<joint>`` (the topic's namespace, else the topic) to the reason.

        """
        out = {}
        for topic, joints, *_ in self.others:
            space = _namespace(topic) or topic
            for joint in joints:
                out[f'{space}/{joint}'] = (
                    f'not analysed: {topic} also holds motor/link pairs, and twin.joints '
                    f'in --config chose joints of {self.link_topic}; analyse it with '
                    f'twin.link_topic: {topic} in --config')
        return out


def _topic_list(bag):
    if not bag.topics:
        return 'no topics'
    return ', '.join(f'{name} ({t.msgtype})' for name, t in bag.topics.items())


def check_configured_topics(bag, settings):
    """Refuse a topic that ``--config`` names and the bag does not have."""
    for key, topic in settings.configured_topics:
        if topic not in bag.topics:
            raise BagError(f'{bag.path}: {key} {topic} set in --config is not in the bag; '
                           f'found: {_topic_list(bag)}')


def _first_names(bag, topic, malformed=None, every=False):
    """
    Joint names of the first readable messages of a topic (count malformed ones before).

    With ``every``, the names of all its messages, in order of first appearance: a name
    the first messages lack (a second broadcaster that starts late) is found too, at
    the cost of reading the whole topic.
    """
    batches = bag.iter_joint_states([topic])
    names = {}
    try:
        for _, decoded in batches:
            if decoded.rejected and malformed is not None:
                count, first = malformed.get(topic, (0, decoded.rejected[0][1]))
                malformed[topic] = (count + len(decoded.rejected), first)
            if len(decoded):
                if not every:
                    return decoded.names
                names.update(dict.fromkeys(decoded.names))
    finally:
        batches.close()
    return tuple(names)


READABLE_ENCODINGS = ('cdr', ROS1)
"""Message encodings of JointState topics the twin decodes."""


def plan_joints(bag, settings):
    """
    Find the JointState topics and motor/link pairs by the ingestion node's rules.

    Combined form: one topic whose messages name ``<joint>`` and
    ``<joint><motor_suffix>``. Split form: ``motor_topic`` (configured, or a
    JointState topic whose name contains ``motor``, or a DynamicJointState topic)
    names the same joints as the link topic (or ``<joint><motor_suffix>``). The
    configured ``link_topic`` is used when the bag has it, else the topic that holds
    pairs. A DynamicJointState topic counts as a JointState topic with ``<joint>`` and
    ``<joint><motor_suffix>`` entries
    (:mod:`reducer_twin.msg_adapters.dynamic_joint_state`): alone, or beside
    ``/joint_states`` that has no motor entries, it gives the combined form.

    Parameters
    ----------
    bag : Bag
        Opened bag.
    settings : AnalysisSettings
        Topics, suffix and joints.

    Returns
    -------
    JointPlan
        Topics and joints.

    Raises
    ------
    BagError
        If the bag has no JointState topic (naming the topics it has), no pairs, or
        lacks a configured joint or topic.

    Notes
    -----
    The names are those of each topic's first readable messages (one storage chunk):
    reading every message to plan would cost the analysis a second read. A pair the
    first messages lack is found by the analysis as it reads (:func:`late_joints`); a
    bag whose first messages give no pair, or lack a configured joint, is planned
    again from the names of all its messages before it is refused.

    """
    states = [n for n, t in bag.topics.items() if t.msgtype in JOINT_STATE_TYPES]
    if not states:
        raise BagError(f'{bag.path}: no {JOINT_STATE} topic; found: {_topic_list(bag)} '
                       f'(and no {JOINT_STATE_TYPES[1]})')
    states = _readable(bag, states)     # said once, whichever plan stands
    try:
        return _plan_joints(bag, settings, states, every=False)
    except BagError:
        # A joint may first appear later in the recording (a second broadcaster that
        # starts late): the whole topics are read before the bag is refused.
        return _plan_joints(bag, settings, states, every=True)


def _readable(bag, states):
    """
    Return the JointState topics in an encoding the twin reads (CDR, ROS 1), others said.

    An MCAP written by another tool may carry JointState as JSON or Protobuf (a Foxglove
    bridge's recording): read as CDR, every message was "malformed", which did not name
    the cause. Topics in such an encoding are left out with a WARNING; when no topic
    is left, the ERROR names the encodings.
    """
    encoding = {t: bag.topic_details[t].serialization_format for t in states}
    other = {t: e for t, e in encoding.items() if e and e not in READABLE_ENCODINGS}
    said = '; '.join(f'{t} carries its messages encoded as {e!r}' for t, e in other.items())
    readable = [t for t in states if t not in other]
    if other and not readable:
        raise BagError(f'{bag.path}: {said}; reducer-twin reads JointState as rosbag2 records '
                       "it (CDR) or a ROS 1 bag: record the topics with 'ros2 bag record' "
                       '(another tool, such as a Foxglove bridge, may write JSON)')
    if other:
        warn(bag, f'{said}: left out (reducer-twin reads CDR, as rosbag2 records it)')
    return readable


def _plan_joints(bag, settings, states, every):
    names, malformed = {}, {}

    def names_of(topic):
        if topic not in names:
            names[topic] = _first_names(bag, topic, malformed, every)
        return names[topic]

    suffix = settings.motor_suffix
    if settings.motor_topic:
        for topic in (settings.link_topic, settings.motor_topic):
            if topic not in states:
                raise BagError(f'{bag.path}: configured JointState topic {topic} is not in the '
                               f'bag; its JointState topics: {states}')
        link, motor = settings.link_topic, settings.motor_topic
        return _pick(bag, settings, link, motor,
                     *_motor_entries(names_of(link), names_of(motor), suffix))
    candidates = [settings.link_topic] if settings.link_topic in states else []
    candidates += [t for t in states if t not in candidates]
    found = _paired_topics(candidates, states, bag, names_of, suffix)
    if found:
        (link, motor), (pairs, motor_names) = found[0]
        plan = _pick(bag, settings, link, motor, pairs, motor_names)
        if settings.joints is None:
            paired = set(plan.joints) | set(plan.motor_names)
            plan = replace(plan, unpaired=tuple(n for n in names_of(link) if n not in paired))
        if settings.configured_topics:     # the configuration chose the topic
            return plan
        # Never silent: another robot (or arm) in the same recording is named.
        used = {link, motor} - {None}
        others = tuple((topic, tuple(joints), other, tuple(motor_names))
                       for (topic, other), (joints, motor_names) in found[1:]
                       if topic not in used and other not in used)
        return replace(plan, others=others)
    if not any(names_of(t) for t in states):
        problems = ''.join(f'; {t}: {n:,} malformed messages, the first: {first}'
                           for t, (n, first) in malformed.items())
        problems += ''.join(f'; {w}' for w in bag.warnings)
        raise BagError(f'{bag.path}: no readable message on its JointState topics {states}'
                       f'{problems}')
    found = '; '.join(f'{t}: {list(names_of(t))[:12]}' for t in states)
    dynamic = any(bag.topics[t].msgtype != JOINT_STATE for t in states)
    hint = (f'; a DynamicJointState joint gives <joint>{suffix} from its interface '
            f'{settings.interfaces.motor_position!r} (twin.interfaces.motor_position)'
            if dynamic else '')
    guess = suffix_guess([names_of(t) for t in states])
    if guess is not None:
        hint += (f'; its entries pair as <joint> and <joint>{guess[0]} ({guess[1]}): if those '
                 f'are the motor encoders, set twin.motor_suffix: {guess[0]!r} in --config')
    raise BagError(f'{bag.path}: no motor/link encoder pairs: expected <joint> and '
                   f'<joint>{suffix} in one JointState message, or a motor JointState topic '
                   f'(twin.motor_topic in --config){hint}; JointState topics and names: '
                   f'{found}')


def suffix_guess(name_lists):
    """
    Return the suffix that pairs a topic's entries as ``<joint>`` and ``<joint><suffix>``.

    Said, never used: a second link encoder named so would pair as well, and only the
    user knows which entries are the motors'. A suffix must not continue the joint's
    name (a digit or a lower-case letter first: ``joint_1``/``joint_10``, ``arm``/``arms``).

    Parameters
    ----------
    name_lists : iterable of iterable of str
        The entry names of each JointState topic.

    Returns
    -------
    tuple or None
        ``(suffix, example)``: the suffix that pairs the most entries (ties: the shorter,
        then the first in order) and up to three pairs as text; None when none pairs.

    """
    pairs = {}
    for names in name_lists:
        have = sorted(set(names))
        for joint in have:
            for entry in have:
                tail = entry[len(joint):]
                continues = tail[:1].isdigit() or tail[:1].islower()
                if tail and entry.startswith(joint) and not continues:
                    pairs.setdefault(tail, []).append(f'{joint} with {entry}')
    if not pairs:
        return None
    best = min(pairs, key=lambda tail: (-len(pairs[tail]), len(tail), tail))
    return best, ', '.join(pairs[best][:3])


def say_unpaired(bag, plan, analysed, settings):
    """
    Warn of entries of the link topic that paired with nothing, so were not analysed.

    A joint whose motor encoder is not published (or named otherwise) would otherwise
    vanish without a word; a gripper's fingers are named too, in one line that changes
    no exit status (``twin.joints`` in ``--config`` chooses the joints and silences it).

    Parameters
    ----------
    bag : Bag
        The bag (the warning is added to it).
    plan : JointPlan
        The plan from the first messages (:attr:`JointPlan.unpaired`).
    analysed : collection of str
        Entry names analysed in the end (joints found late included), without prefix.
    settings : AnalysisSettings
        The motor entries' suffix and DynamicJointState interfaces.

    """
    suffix = settings.motor_suffix
    lone = [n for n in plan.unpaired if n not in analysed]
    links = [n for n in lone if not (suffix and n.endswith(suffix))]
    motors = [n for n in lone if suffix and n.endswith(suffix)]
    parts = []
    if links:
        where = f' on {plan.motor_topic}' if plan.motor_topic else ''
        parts.append(f'{_listed(links)} without a motor entry (<joint>{suffix}{where})')
    if motors:
        parts.append(f'{_listed(motors)} without a link entry')
    if not parts:
        return
    names = ('twin.motor_suffix, twin.motor_topic' if bag.topics[plan.link_topic].msgtype
             == JOINT_STATE else f'its interface {settings.interfaces.motor_position!r}: '
             'twin.interfaces.motor_position')
    warn(bag, f'{plan.link_topic} also carries {" and ".join(parts)}: not analysed; a '
         "reducer among them needs both its encoders published under the twin's names "
         f'({names}; twin.joints chooses the joints)')


def _listed(names, most=8):
    """Return up to ``most`` names, comma-separated, and how many more."""
    more = f' and {len(names) - most} more' if len(names) > most else ''
    return ', '.join(names[:most]) + more


def late_joints(plan, seen, settings):
    """
    Plan the pairs an analysis met that its plan, made from the first messages, lacks.

    Parameters
    ----------
    plan : JointPlan
        The plan analysed (entry names with its ``prefix``).
    seen : dict of str to iterable of str
        Per topic of the plan, every entry name its messages carried (prefixed).
    settings : AnalysisSettings
        Suffix and configured joints.

    Returns
    -------
    JointPlan or None
        The same topics with the joints found late (the motor/link pairing rules of
        :func:`plan_joints`); None when there is none, or ``twin.joints`` chose the
        joints.

    """
    if settings.joints is not None:
        return None
    suffix = settings.motor_suffix
    link = [n for n in seen.get(plan.link_topic, ()) if n not in plan.joints]
    if plan.motor_topic is None:
        have = set(seen.get(plan.link_topic, ()))
        joints = [n for n in link if n + suffix in have]
        entries = [n + suffix for n in joints]
    else:
        # The motor topic's entries carry no prefix beyond the plan's own.
        motor = [n[len(plan.prefix):] for n in seen.get(plan.motor_topic, ())]
        bare, entries = _motor_entries([n[len(plan.prefix):] for n in link], motor, suffix)
        joints = [plan.prefix + n for n in bare]
        entries = [plan.prefix + n for n in entries]
    if not joints:
        return None
    return JointPlan(plan.link_topic, plan.motor_topic, tuple(joints), tuple(entries),
                     prefix=plan.prefix)


def _motor_entries(link_names, motor_names, suffix):
    """Joints of a link topic found on a motor topic, as ``<joint>`` or ``<joint><suffix>``."""
    have = set(motor_names)
    joints, entries = [], []
    for name in link_names:
        for entry in (name + suffix, name):
            if entry in have:
                joints.append(name)
                entries.append(entry)
                break
    return joints, entries


def _namespace(topic):
    """Return a topic's namespace without slashes (``'/robot_b/joint_states'``: ``robot_b``)."""
    return topic.rsplit('/', 1)[0].strip('/')


def robot_plans(bag, plan, settings):
    """
    Every robot's plan when a recording holds several (one per paired link topic).

    Each robot's joints are named ``<namespace>/<joint>`` (the topic's namespace; none
    for a topic at the root): two arms with the same joint names stay apart. With
    ``twin.joints`` configured only the plan given is analysed (the others are said).

    Returns
    -------
    list of JointPlan
        The plans, the given one first; just it when there is no other robot.

    """
    if not plan.others or settings.joints is not None:
        return [plan]
    plans = []
    for topic, joints, motor, motor_names in ((plan.link_topic, plan.joints, plan.motor_topic,
                                               plan.motor_names), *plan.others):
        space = _namespace(topic)
        prefix = f'{space}/' if space else ''
        plans.append(JointPlan(topic, motor, tuple(prefix + j for j in joints),
                               tuple(prefix + m for m in motor_names), prefix=prefix))
    return plans


def _paired_topics(candidates, states, bag, names_of, suffix):
    """
    Every link topic with motor/link pairs, in order of preference.

    Returns
    -------
    list of tuple
        ``((link topic, motor topic or None), (joints, motor entry names))``: the
        combined form first (one topic with ``<joint>`` and ``<joint><suffix>``), then
        the split form (a motor JointState topic, or a DynamicJointState one, naming
        the link topic's joints).

    """
    found = []
    for link in candidates:
        have = names_of(link)
        pairs = [n for n in have if n + suffix in have]
        if pairs:
            found.append(((link, None), (pairs, [n + suffix for n in pairs])))
    dynamic = [t for t in states if bag.topics[t].msgtype != JOINT_STATE]
    combined = {link for (link, _), _ in found}
    for link in candidates:
        if link in combined or 'motor' in link.lower():
            continue
        for motor in [t for t in states if t != link and ('motor' in t.lower() or t in dynamic)]:
            common, motor_names = _motor_entries(names_of(link), names_of(motor), suffix)
            if common:
                found.append(((link, motor), (common, motor_names)))
                break
    return found


def _pick(bag, settings, link, motor, available, motor_names):
    lookup = dict(zip(available, motor_names))
    if settings.joints is None:
        joints = tuple(available)
    else:
        missing = [j for j in settings.joints if j not in lookup]
        if missing:
            raise BagError(f'{bag.path}: configured joints {missing} have no motor/link pair '
                           f'on {link}{" and " + motor if motor else ""}; pairs found: '
                           f'{list(available)}')
        joints = tuple(settings.joints)
    if not joints:
        raise BagError(f'{bag.path}: {link} and {motor} name no common joints')
    return JointPlan(link, motor, joints, tuple(lookup[j] for j in joints))
