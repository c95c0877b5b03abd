"""One joint of the twin: its topics, processing and results, shared by nodes and analysis."""

TOPIC_NAMESPACE = 'reducer_twin'
"""Namespace of every derived topic."""


def joint_topic(joint, suffix, namespace=TOPIC_NAMESPACE):
    """Return the topic of a derived value of one joint, ``/reducer_twin/<joint>/<suffix>``."""
    return f'/{namespace}/{joint}/{suffix}'
