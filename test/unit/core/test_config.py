"""Every parameter is declared once, in core/parameters.py (the merger's table) or node_config.py
(the node's): MergeConfig's and NodeConfig's fields, config/map_merge.yaml, the README's parameter
table and the names the node reads are derived from them or checked against them here. A
parameter declared anywhere else fails."""
import ast
import os
import pickle
import re
from dataclasses import fields

import pytest
import yaml
from conftest import REPO

from multi_map_merge import node_config
from multi_map_merge.cli import params_doc
from multi_map_merge.core import parameters as P
from multi_map_merge.core.config import MergeConfig
from multi_map_merge.node_config import NodeConfig

ALL = {p.name: p for p in node_config.parameters()}


def read(*path):
    with open(os.path.join(REPO, *path)) as f:
        return f.read()


def test_each_parameter_is_in_one_table_once():
    names = [p.name for p in node_config.parameters()]
    assert len(names) == len(set(names))
    aliases = [a for p in node_config.parameters() for a in list(p.former) + [o for o, _ in p.mexplore + p.deprecated]]
    assert len(aliases) == len(set(aliases)) and not set(aliases) & set(names)
    assert set(P.MERGER.names()).isdisjoint(node_config.NODE.names())
    assert not any(p.library for p in P.MERGER.rows)   # library parameters are the node's
    assert node_config.TABLES == (P.MERGER, node_config.NODE) and P.TABLES == (P.MERGER,)


@pytest.mark.parametrize('config,rows', [(MergeConfig, P.config_parameters),
                                         (NodeConfig, node_config.config_parameters)])
def test_configs_fields_are_the_tables_parameters_with_their_defaults(config, rows):
    d = config()
    assert [f.name for f in fields(config)] == [p.name for p in rows()]
    for p in rows():
        assert getattr(d, p.name) == p.default, p.name
        assert p.convert(p.default) == p.default, p.name   # each default passes its own rule
    assert issubclass(NodeConfig, MergeConfig)   # the merger takes the node's configuration as it is
    assert not set(node_config.NODE.names()) & {f.name for f in fields(MergeConfig)}
    assert MergeConfig.RENAMED == {'min_reliability': 'min_inlier_ratio', 'transforms_file': 'state_file'}
    assert MergeConfig().initial_poses is not MergeConfig().initial_poses   # mutable defaults not shared


@pytest.mark.parametrize('config,module', [(MergeConfig, 'multi_map_merge.core.config'),
                                           (NodeConfig, 'multi_map_merge.node_config')])
def test_configs_are_written_out_field_by_field_with_each_parameters_type(config, module):
    """Each is a plain dataclass (its fields readable in its module); each field's declared type
    is its parameter's kind, and it pickles by its own name (the worker processes)."""
    kinds = {'bool': 'bool', 'int': 'int', 'double': 'float', 'string': 'str', 'string list': 'List[str]',
             'double list': 'List[float]', 'dict': 'Dict[str, List[float]]'}
    declared = {f.name: f.type for f in fields(config)}
    for p in node_config.config_parameters():
        if p.name in declared:
            assert declared[p.name] == kinds[p.kind], p.name
    assert config.__module__ == module
    c = config(workers=3, initial_poses={'a': [1.0, 2.0, 0.5]})
    assert pickle.loads(pickle.dumps(c)) == c


def test_every_parameter_has_a_unit_or_none_a_meaning_and_a_type():
    for p in node_config.parameters():
        assert p.meaning and '\n' not in p.meaning and '|' not in p.doc, p.name
        assert p.kind in ('bool', 'int', 'double', 'string', 'string list', 'double list', 'dict'), p.name
        assert p.section, p.name
    units = {p.name: p.unit for p in node_config.parameters()}
    assert units['merge_rate'] == 'Hz' and units['stale_map_timeout'] == 's' and units['map_drift'] == 'm/m'


def test_committed_yaml_is_generated_from_the_tables():
    """tools/gen_params.py writes it: run it after editing core/parameters.py or node_config.py."""
    assert read('config', 'map_merge.yaml') == params_doc.yaml_text()


def test_yaml_names_and_defaults_are_the_tables():
    y = yaml.safe_load(read('config', 'map_merge.yaml'))
    assert set(y) == {p.name for p in node_config.config_parameters()}
    for name, value in y.items():
        assert value == ALL[name].default, name


def test_readme_parameter_table_is_generated_from_the_tables():
    """The block between the markers is tools/gen_params.py's (the README may move it whole)."""
    text = read('README.md')
    assert text.count(params_doc.README_BEGIN) == 1 and text.count(params_doc.README_END) == 1
    assert params_doc.markdown_table() in text


def test_no_readme_parameter_row_outside_the_tables():
    """Every row `| ~name | ...` of a README table with a default column is a parameter of the
    tables, with the table's default; none is documented outside the generated block."""
    text = read('README.md')
    block = text[text.index(params_doc.README_BEGIN):text.index(params_doc.README_END)]
    outside = text.replace(block, '')
    header = None
    for line in text.splitlines():
        if not line.startswith('|'):
            header = None
            continue
        if header is None:
            header = [c.strip() for c in line.strip('|').split('|')]
            continue
        m = re.match(r'^\| `~(\w+)` \|', line)
        if not m or 'default' not in header:
            continue
        name = m.group(1)
        assert name in ALL, 'README documents ~%s, which no table declares' % name
        assert line not in outside, 'README documents ~%s outside the generated block' % name
        cells = [c.strip() for c in line.strip('|').split(' | ')]
        assert cells[header.index('default')] == params_doc._md_default(ALL[name]), name


def _node_modules():
    """ros/node.py and the modules of ros/ it imports, directly or through each other (the
    map_merge node's code)."""
    mods, todo = set(), ['node']
    while todo:
        m = todo.pop()
        if m in mods or not os.path.exists(os.path.join(REPO, 'src', 'multi_map_merge', 'ros', m + '.py')):
            continue
        mods.add(m)
        todo += re.findall(r'^from \.(\w+) import', read('src', 'multi_map_merge', 'ros', m + '.py'), re.M)
    return sorted(os.path.join(REPO, 'src', 'multi_map_merge', 'ros', m + '.py') for m in mods)


def test_the_node_reads_no_private_parameter_outside_the_tables():
    """A rospy.get_param('~x' ...) (or _cached, has_param, search_param) in the node's code names
    a parameter of the tables, and a default given there is the table's."""
    seen = 0
    for path in _node_modules():
        with open(path) as f:
            tree = ast.parse(f.read(), path)
        for call in ast.walk(tree):
            if not (isinstance(call, ast.Call) and isinstance(call.func, ast.Attribute)
                    and call.func.attr in ('get_param', 'get_param_cached', 'has_param', 'search_param')
                    and call.args and isinstance(call.args[0], ast.Constant)
                    and isinstance(call.args[0].value, str) and call.args[0].value.startswith('~')):
                continue
            name = call.args[0].value[1:]
            if name == '':
                continue   # the whole private namespace: resolved by the tables
            seen += 1
            assert name in ALL, '%s:%d reads ~%s, which no table declares' % (path, call.lineno, name)
            if len(call.args) > 1:
                default = ast.literal_eval(call.args[1])
                assert default == ALL[name].default, '%s:%d: default of ~%s' % (path, call.lineno, name)
    assert seen >= 1   # ~diagnostic_period, read again while running


@pytest.mark.parametrize('path', [('core', 'parameters.py'), ('node_config.py',)])
def test_the_tables_modules_are_ros_free(path):
    tree = ast.parse(read('src', 'multi_map_merge', *path))
    imported = {a.name.split('.')[0] for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    imported |= {n.module.split('.')[0] for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module}
    assert not imported & {'rospy', 'rosgraph', 'roslib', 'yaml', 'numpy'}


def test_the_core_knows_nothing_of_the_node():
    """The node's table is out of core/: no module of core/ imports it, and the core's config and
    resolver do not know the node's parameters."""
    core = os.path.join(REPO, 'src', 'multi_map_merge', 'core')
    for name in sorted(os.listdir(core)):
        if name.endswith('.py'):
            text = read('src', 'multi_map_merge', 'core', name)
            assert 'node_config' not in re.sub(r'""".*?"""|#.*', '', text, flags=re.S), name
    with pytest.raises(P.ParameterError) as e:
        MergeConfig.from_dict({'merge_rate': 2.0})
    assert 'unknown parameter merge_rate' in str(e.value)


# -- MergeConfig.from_dict: the front ends' (merge_maps --config, evaluate_map) use of the resolver

def test_from_dict_converts_types():
    c = MergeConfig.from_dict({'min_inliers': '12', 'refine': 0, 'robots': 'tb3_0 tb3_1'})
    assert c.min_inliers == 12 and c.refine is False and c.robots == ['tb3_0', 'tb3_1']


def test_from_dict_of_the_shipped_yaml_is_the_defaults():
    assert NodeConfig.from_dict(yaml.safe_load(read('config', 'map_merge.yaml'))) == NodeConfig()


def test_a_renamed_parameter_is_still_read_by_its_old_name():
    assert MergeConfig.from_dict({'min_reliability': '0.3'}).min_inlier_ratio == 0.3
    assert MergeConfig.from_dict({'min_reliability': 0.3, 'min_inlier_ratio': 0.2}).min_inlier_ratio == 0.2
    assert MergeConfig.from_dict({'transforms_file': 'links.yaml'}).state_file == 'links.yaml'
    # ours at its default (as config/map_merge.yaml sets every parameter): the former name is meant
    assert MergeConfig.from_dict({'min_reliability': 0.3, 'min_inlier_ratio': 0.0}).min_inlier_ratio == 0.3


def test_from_dict_reads_mexplore_names_and_warns_as_the_node_does():
    warned = []
    c = NodeConfig.from_dict({'merging_rate': 4.0, 'init_pose_params': True, 'merge_rate': 3.0},
                             warn=warned.append)
    assert c.merge_rate == 3.0 and c.known_init_poses is True
    assert len(warned) == 2 and any('deprecated' in w for w in warned) and any('wins' in w for w in warned)


@pytest.mark.parametrize('given,words', [
    ({'min_agreement': 1.5}, ['min_agreement = 1.5 is invalid', '[0, 1]']),
    ({'merge_rate': 0}, ['merge_rate = 0 is invalid', '> 0']),
    ({'max_cells': 'many'}, ['max_cells', 'integer >= 1']),
    ({'initial_pose_tolerance': [1.0]}, ['initial_pose_tolerance', '[metres, radians]']),
    ({'free_thresh': 70, 'occupied_thresh': 60}, ['free_thresh (70) must be below occupied_thresh (60)']),
    ({'min_agreemnt': 0.5}, ['unknown parameter min_agreemnt: did you mean min_agreement?']),
    ({'zzzz': 1}, ['unknown parameter zzzz']),
    ({'merging_rate': -1}, ['merge_rate (given as merging_rate) = -1 is invalid']),
])
def test_from_dict_refuses_bad_values_and_unknown_names(given, words):
    with pytest.raises(P.ParameterError) as e:
        NodeConfig.from_dict(given)
    for w in words:
        assert w in str(e.value), str(e.value)
    assert 'using the default' not in str(e.value)


def test_from_dict_names_every_error_at_once():
    with pytest.raises(ValueError) as e:
        MergeConfig.from_dict({'min_agreement': 2, 'workers': -1, 'x_y': 1})
    assert len(str(e.value).splitlines()) == 3


def test_from_dict_needs_a_mapping_of_names():
    with pytest.raises(P.ParameterError):
        NodeConfig.from_dict(['merge_rate', 2])
    with pytest.raises(P.ParameterError) as e:
        NodeConfig.from_dict({1: 2, 'merge_rate': 2})   # (YAML reads `1: 2` so)
    assert 'names must be strings' in str(e.value)


def test_offline_reference_need_not_match_the_nodes_discovery_pattern():
    """evaluate_map's merger names its reference 'truth'; merge_maps' are file stems."""
    assert MergeConfig.from_dict({'workers': 1, 'reference_robot': 'truth'}).reference_robot == 'truth'


def test_generator_script_check_passes():
    import subprocess
    import sys
    r = subprocess.run([sys.executable, os.path.join(REPO, 'tools', 'gen_params.py'), '--check'],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stdout + r.stderr


def test_readme_mexplore_table_names_every_alias_and_only_known_parameters():
    """The README's *Switching from m-explore* table: each m-explore name the tables read is a
    row naming the parameter it is read as; every row's parameter is one of the tables."""
    text = read('README.md')
    rows = re.findall(r'^\| `(\w+)` \| (?:`~(\w+)`[^|]*|none) \|', text, re.M)
    here = {m: ours for m, ours in rows}
    for p in P.parameters():
        for alias, _ in p.mexplore:
            assert here.get(alias) == p.name, (alias, p.name)
    for alias in P.MEXPLORE_IGNORED:
        assert here.get(alias) == '', alias
    for m, ours in rows:
        assert not ours or ours in ALL, 'README maps %s to ~%s, which no table declares' % (m, ours)
