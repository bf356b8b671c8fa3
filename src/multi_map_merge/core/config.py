"""The merger's typed configuration: :class:`MergeConfig`, whose fields, types and defaults are
the parameters of :data:`.parameters.MERGER` (their meaning, unit and accepted values are
declared there; a unit test checks the two agree field by field). The node's configuration adds
its own fields to it (:class:`multi_map_merge.node_config.NodeConfig`)."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Callable, ClassVar, Dict, List, Optional, Sequence

from . import parameters as _params


@dataclass
class MergeConfig:
    """The merger's parameters (:data:`.parameters.MERGER`): one field per parameter, in the
    table's order, its default the table's. Units are the table's (``python3 -m
    multi_map_merge.cli.params_doc --markdown`` prints it)."""

    #: our former names: old name -> name (the old one is still read)
    RENAMED: ClassVar[Dict[str, str]] = _params.renamed()
    #: the tables its fields come from
    TABLES: ClassVar[Sequence[_params.Table]] = _params.TABLES

    robots: List[str] = field(default_factory=list)
    reference_robot: str = ''
    merged_map_frame: str = 'map'
    free_thresh: float = 19.6   # percent
    occupied_thresh: float = 65.0   # percent
    max_cells: int = 25_000_000   # cells
    akaze_threshold: float = 0.0003
    max_features: int = 2000
    feature_cells: int = 120_000   # cells
    match_candidates: int = 2
    match_ratio: float = 0.8
    ransac_threshold: float = 3.0   # cells
    ransac_iterations: int = 15_000
    ransac_hypotheses: int = 8
    min_matches: int = 10
    min_inliers: int = 10
    min_inlier_ratio: float = 0.0
    few_inliers: int = 21
    few_inliers_min_agreement: float = 0.96
    replace_margin: float = 0.02
    refine: bool = True
    min_agreement: float = 0.8
    min_overlap_cells: int = 400   # cells
    agreement_tolerance: int = 2   # cells
    pose_graph: bool = True
    joint_placement: bool = True
    ambiguity_margin: float = 0.1
    max_position_sigma: float = 0.1   # m
    map_drift: float = 0.02   # m/m
    map_drift_yaw: float = 0.4   # deg/sqrt(m)
    bend_maps: bool = False
    bend_node_spacing: float = 2.5   # m
    initial_poses: Dict[str, List[float]] = field(default_factory=dict)   # m, m, rad
    initial_pose_tolerance: List[float] = field(default_factory=lambda: [1.0, 0.35])   # m, rad
    trust_initial_poses: bool = False
    known_init_poses: bool = False
    workers: int = 0   # processes
    estimation_budget: float = 5.0   # s
    refresh_links: bool = True
    dask_scheduler: str = ''
    state_file: str = ''

    @classmethod
    def from_dict(cls, d: Dict[str, Any], warn: Optional[Callable[[str], None]] = None) -> 'MergeConfig':
        """Build from a mapping (name -> value, as config/map_merge.yaml has them) through the one
        resolver (:func:`.parameters.resolve_strictly`) over the class's tables: values converted
        to each field's type; m-explore's names and former names read as the node reads them. A
        value out of range, of the wrong type, or a name no parameter of those tables has raises
        :class:`.parameters.ParameterError` (a ValueError) naming each; warnings (an alias
        overridden, a deprecated name) go to ``warn``."""
        res = _params.resolve_strictly(d, tables=cls.TABLES)
        if warn is not None:
            for line in res.warnings:
                warn(line)
        return cls(**{p.name: res.values[p.name] for p in _params.config_parameters(cls.TABLES)})

    def to_dict(self) -> Dict[str, Any]:
        return dataclasses.asdict(self)
