"""One typed configuration for the whole merger; ``config/map_merge.yaml`` holds the same
defaults for ROS users (a unit test keeps the two equal)."""
from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields
from typing import Any, ClassVar, Dict, List


@dataclass
class MergeConfig:
    # --- which maps (node only) ---
    robot_namespace_pattern: str = 'tb3_*'   # fnmatch pattern of <robot> in /<robot>/map topics
    robots: List[str] = field(default_factory=list)  # explicit robot namespaces; empty = discover
    map_topic: str = 'map'                   # per-robot topic name under its namespace
    map_updates_topic: str = ''              # per-robot updates topic; '' = <map_topic>_updates
    merged_map_topic: str = 'map'            # output topic of the merged map (and <it>_metadata)
    reference_robot: str = ''                # '' = the first robot in name order (robot 1): merger.decide_reference
    merged_map_frame: str = 'map'            # frame of the merged map and parent of every TF
    # --- rates (node only), Hz ---
    estimation_rate: float = 0.5
    merge_rate: float = 2.0
    discovery_rate: float = 0.5
    tf_rate: float = 20.0
    # --- input health (node only) ---
    stale_map_timeout: float = 30.0          # s: a robot whose last map is older is WARN; 0 = off
    # --- grid -> image ---
    free_thresh: float = 19.6                # percent: 0..free_thresh is free
    occupied_thresh: float = 65.0            # percent: >= occupied_thresh is occupied
    max_cells: int = 25_000_000              # a grid larger than this is rejected
    # --- features and matching ---
    akaze_threshold: float = 0.0003          # lower finds more features (small maps need them)
    max_features: int = 2000                 # strongest features kept per map; 0 = all
    feature_cells: int = 120_000             # larger known areas are described coarser; 0 = never
    match_candidates: int = 2                # nearest neighbours kept per feature
    match_ratio: float = 0.8                 # Lowe's ratio, only to score reliability
    # --- RANSAC and reliability ---
    ransac_threshold: float = 3.0            # cells
    ransac_iterations: int = 15000           # two-point samples (cheap: most fail the length test)
    ransac_hypotheses: int = 8               # distinct transforms verified per pair
    min_matches: int = 10
    min_inliers: int = 10
    min_inlier_ratio: float = 0.0            # inlier ratio below this is never used
    few_inliers: int = 21                    # a link with fewer RANSAC inliers than this ...
    few_inliers_min_agreement: float = 0.96  # ... must verify at least this well; 0 = off
    replace_margin: float = 0.02             # a new transform must beat the kept one by this
    # --- verification on the grids (beyond the paper) ---
    refine: bool = True                      # ICP of wall cells after RANSAC
    min_agreement: float = 0.8               # wall agreement 0..1 in the overlap
    min_overlap_cells: int = 400
    agreement_tolerance: int = 2             # cells
    pose_graph: bool = True                  # place robots by all verified links at once (cycles averaged)
    joint_placement: bool = True             # then refine each placement against every placed map (core/joint.py)
    ambiguity_margin: float = 0.1            # a 2nd placement verifying within this agreement: unmerged; 0 = off
    max_position_sigma: float = 0.1          # m: a placement whose 2-sigma position exceeds this is weakly pinned
    map_drift: float = 0.02                  # m per m from its origin a map's walls sit off (1 sigma, core/drift.py)
    map_drift_yaw: float = 0.4               # deg per sqrt(m) from a map's origin its walls sit turned (1 sigma)
    bend_maps: bool = False                  # merged map: bend each placed map onto the others' walls (core/deform.py)
    bend_node_spacing: float = 2.5           # m between a bent map's nodes
    # --- prior knowledge of where robots started (optional). A prior is the pose of a robot's map
    # frame in one frame common to all priors; only differences count (the merged frame is the
    # reference robot's map frame, and a link is checked against prior_ref^-1 * prior_robot) ---
    initial_poses: Dict[str, List[float]] = field(default_factory=dict)  # robot: [x, y, yaw]
    initial_pose_tolerance: List[float] = field(default_factory=lambda: [1.0, 0.35])  # m, rad
    trust_initial_poses: bool = False        # place robots with no verified link at their prior
    known_init_poses: bool = False           # node: read m-explore's /<robot>/map_merge/init_pose_{x,y,yaw}
    # --- speed ---
    workers: int = 0                         # estimation processes; 0 = one per core (small maps inline), 1 = inline
    # --- persistence (node only) ---
    state_file: str = ''                     # the merger's state file (core/state.py); '' = none

    # parameters renamed since they were published: old name -> new name (the old one is still read)
    RENAMED: ClassVar[Dict[str, str]] = {'min_reliability': 'min_inlier_ratio',
                                         'transforms_file': 'state_file'}

    @classmethod
    def former_name_wins(cls, given: Dict[str, Any], old: str) -> bool:
        """Whether ``given`` (parameters by name) is read by the former name ``old`` of a
        renamed parameter (:attr:`RENAMED`): it is given, and the new name is absent or at its
        default. config/map_merge.yaml lists every parameter at its default, so a launch file
        that loads it and sets a former name means the former name's value."""
        new = cls.RENAMED[old]
        return old in given and (given.get(new) is None or given[new] == getattr(cls(), new))

    @classmethod
    def from_dict(cls, d: Dict[str, Any]) -> 'MergeConfig':
        """Build from a mapping, ignoring unknown keys; values are converted to each field's type.
        A parameter's former name (:attr:`RENAMED`) is read as :meth:`former_name_wins` says."""
        d = dict(d)
        for old, new in cls.RENAMED.items():
            if cls.former_name_wins(d, old):
                d[new] = d[old]
        kw = {}
        for f in fields(cls):
            if f.name in d and d[f.name] is not None:
                default = getattr(cls(), f.name)
                v = d[f.name]
                if isinstance(default, bool):
                    v = bool(v)
                elif isinstance(default, int):
                    v = int(v)
                elif isinstance(default, float):
                    v = float(v)
                elif f.name == 'initial_pose_tolerance':
                    v = [float(x) for x in v]
                    if len(v) != 2:
                        raise ValueError('initial_pose_tolerance needs [metres, radians]')
                elif isinstance(default, dict):
                    if not isinstance(v, dict):
                        raise ValueError('%s must be a mapping robot: [x, y, yaw]' % f.name)
                    v = {str(k): [float(x) for x in p] for k, p in v.items()}
                    if any(len(p) != 3 for p in v.values()):
                        raise ValueError('%s: every pose needs [x, y, yaw]' % f.name)
                elif isinstance(default, list):
                    v = [str(x) for x in (v if isinstance(v, (list, tuple)) else str(v).split())]
                else:
                    v = str(v)
                kw[f.name] = v
        return cls(**kw)

    def to_dict(self) -> Dict[str, Any]:
        return asdict(self)
