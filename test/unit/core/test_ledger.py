"""The pair ledger (core/ledger.py): what forgetting a robot, changing its prior and a reset clear."""
import numpy as np

from multi_map_merge.core import schedule
from multi_map_merge.core.ledger import PairLedger
from multi_map_merge.core.links import Link
from multi_map_merge.core.pair import PairResult
from multi_map_merge.core.transforms import se2


def link(a, b, T=None):
    return Link(a, b, se2(1.0, 0.0, 0.0) if T is None else T, 0.9, 0.95, 40, 40, 0.0, 1000)


def filled():
    """A ledger with every record of the pairs (a, b) and (b, c)."""
    led = PairLedger()
    for k in (('a', 'b'), ('b', 'c')):
        led.links[k] = link(*k)
        led.results[k] = PairResult(np.eye(3), 40, 40, 0.9, 0.95, 1000, True)
        led.restored[k] = link(*k)
        led.tried[k] = (1, 2)
        led.aligned[k] = schedule.Aligned(1, 100.0, (10, 10))
        led.refreshed[k] = (10, 10)
        led.pinned[k] = (10, 10)
        led.track_failed.add(k)
        led.drift_covs[k] = ()
    led.cycle = 3
    led.seen_versions = {'a': 1, 'b': 2, 'c': 3}
    led.since_slow = {'a': 1, 'b': 1, 'c': 1}
    return led


def test_forgetting_a_robot_drops_its_links_their_drift_and_its_restored_links_only():
    led = filled()
    assert led.forget('c')
    assert set(led.links) == set(led.restored) == set(led.drift_covs) == {('a', 'b')}
    # its results and schedule records name map versions that never come again: they stay
    assert set(led.results) == set(led.tried) == set(led.aligned) == {('a', 'b'), ('b', 'c')}
    assert not led.forget('c') and not led.forget('z')


def test_a_new_prior_aligns_the_robots_pairs_again_and_drops_its_contradicted_links():
    led = filled()
    priors = {'a': [0.0, 0.0, 0.0], 'b': [5.0, 0.0, 0.0]}   # a -> b 5 m, the link says 1 m
    events = led.reprior('b', priors, (1.0, 0.35))
    assert set(led.links) == {('b', 'c')} and len(events) == 1 and 'a -> b dropped' in events[0]
    assert not led.tried and not led.aligned and not led.refreshed
    assert led.track_failed == {('a', 'b'), ('b', 'c')}
    assert set(led.pinned) == {('a', 'b'), ('b', 'c')}


def test_a_reset_clears_every_pair_record_but_the_restored_links_and_the_counters():
    led = filled()
    led.reset()
    assert not (led.links or led.results or led.tried or led.aligned or led.refreshed or led.pinned
                or led.track_failed or led.drift_covs)
    assert set(led.restored) == {('a', 'b'), ('b', 'c')}
    assert led.cycle == 3 and led.seen_versions and led.since_slow
