"""
Spec: the Foxglove layout shows the derived topics a derived bag really has, field by name.

``config/foxglove/reducer_twin.json`` plots single-record MultiArray topics by index
(``/reducer_twin/<joint>/<layout>.data[i]``); each path's label must be the layout's field
``i``, and each topic must be in the bag that ``analyze`` writes for a two-joint recording.
"""

import json
import re

import pytest
from reducer_twin.analysis.pipeline import analyze_bag
from reducer_twin.analysis.simulate import simulate_bag, SimulationSpec
from reducer_twin.io.bag import open_bag
from reducer_twin.msg_adapters.layouts import LAYOUTS

PATH = re.compile(r'^(/reducer_twin/(\w+)/(\w+))\.data\[(\d+)\]$')


@pytest.fixture(scope='module')
def layout(repo_root):
    """Load the committed layout."""
    return json.loads((repo_root / 'config' / 'foxglove' / 'reducer_twin.json').read_text())


@pytest.fixture(scope='module')
def derived_topics(tmp_path_factory):
    """Analyse a two-joint simulated bag; return the derived bag's topics."""
    root = tmp_path_factory.mktemp('fox')
    simulate_bag(root / 'bag', SimulationSpec(hours=500.0, aging_factor=36000.0, joints=2,
                                              rate_hz=250.0, seed=2))
    result = analyze_bag(root / 'bag', root / 'derived')
    with open_bag(result.out) as bag:
        return set(bag.topics)


def _paths(layout):
    for panel_id, config in layout['configById'].items():
        for entry in config.get('paths', []):
            yield panel_id, entry


def test_every_plotted_path_names_its_layout_field(layout):
    seen = 0
    for panel_id, entry in _paths(layout):
        match = PATH.match(entry['value'])
        assert match, f'{panel_id}: {entry["value"]} is not a /reducer_twin/<joint>/<topic> path'
        _, _, suffix, index = match.groups()
        fields = LAYOUTS[suffix].fields
        assert not LAYOUTS[suffix].batch, f'{suffix} is a batch layout: data[i] is no field'
        assert entry['label'] == fields[int(index)]
        seen += 1
    assert seen >= 20


def test_every_plotted_topic_is_in_a_derived_bag(layout, derived_topics):
    topics = {PATH.match(e['value']).group(1) for _, e in _paths(layout)}
    assert topics <= derived_topics, sorted(topics - derived_topics)
    diagnostics = [c for c in layout['configById'].values() if 'topicToRender' in c]
    assert diagnostics and all(c['topicToRender'] in derived_topics for c in diagnostics)


def test_every_panel_of_the_layout_tree_has_a_config(layout):
    def leaves(node):
        return [node] if isinstance(node, str) else leaves(node['first']) + leaves(
            node['second'])
    assert sorted(leaves(layout['layout'])) == sorted(layout['configById'])
