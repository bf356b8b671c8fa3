import os
from dataclasses import fields

import yaml
from conftest import REPO

from multi_map_merge.core.config import MergeConfig


def test_yaml_defaults_equal_code_defaults():
    """config/map_merge.yaml (what the README documents and launch loads) and MergeConfig
    (what the core uses) name the same parameters with the same defaults."""
    with open(os.path.join(REPO, 'config', 'map_merge.yaml')) as f:
        y = yaml.safe_load(f)
    d = MergeConfig()
    assert set(y) == {f.name for f in fields(MergeConfig)}
    for f in fields(MergeConfig):
        assert y[f.name] == getattr(d, f.name), f.name


def test_readme_documents_every_parameter():
    with open(os.path.join(REPO, 'README.md')) as f:
        text = f.read()
    missing = [f.name for f in fields(MergeConfig) if '`~%s`' % f.name not in text]
    assert not missing, 'README Parameters table lacks: %s' % missing


def test_from_dict_converts_types():
    c = MergeConfig.from_dict({'min_inliers': '12', 'refine': 0, 'robots': 'tb3_0 tb3_1', 'x': 1})
    assert c.min_inliers == 12 and c.refine is False and c.robots == ['tb3_0', 'tb3_1']


def test_a_renamed_parameter_is_still_read_by_its_old_name():
    assert MergeConfig.from_dict({'min_reliability': '0.3'}).min_inlier_ratio == 0.3
    assert MergeConfig.from_dict({'min_reliability': 0.3, 'min_inlier_ratio': 0.2}).min_inlier_ratio == 0.2
    assert MergeConfig.from_dict({'transforms_file': 'links.yaml'}).state_file == 'links.yaml'
    # ours at its default (as config/map_merge.yaml sets every parameter): the former name is meant
    assert MergeConfig.from_dict({'min_reliability': 0.3, 'min_inlier_ratio': 0.0}).min_inlier_ratio == 0.3
