"""make demo's verdict on the placements (lab/demo.py): a robot placed farther than 0.25 m or
3 degrees from its start truth fails it, with a line naming the robot and its error."""
from multi_map_merge.lab.demo import MAX_PLACEMENT_ERROR, placement_failures


def test_the_limits_are_the_issues():
    assert MAX_PLACEMENT_ERROR == (0.25, 3.0)


def test_a_robot_beyond_either_limit_fails_with_its_error():
    # the home's pristine run (docs/demo.md), then its AWS-house tb3_2 at 4.11 degrees
    errs = {'tb3_0': (0.0, 0.0), 'tb3_1': (0.118, 1.53), 'tb3_2': (0.237, 0.01), 'tb3_3': (0.123, 0.87)}
    assert placement_failures(errs, 'tb3_0') == []
    errs.update(tb3_2=(0.05, 4.11), tb3_3=(0.251, 0.2), tb3_1=None)     # tb3_1: not merged (reported apart)
    lines = placement_failures(errs, 'tb3_0', fit_errs={'tb3_2': (0.04, 0.5)})
    assert lines == [
        'FAILED: tb3_2 placed 0.050 m and 4.11 degrees from its start truth (limits 0.25 m, 3.0 degrees); '
        "0.040 m and 0.50 degrees from its own map's best fit",
        'FAILED: tb3_3 placed 0.251 m and 0.20 degrees from its start truth (limits 0.25 m, 3.0 degrees)']


def test_the_reference_and_the_limits_themselves_pass():
    assert placement_failures({'a': (9.0, 90.0), 'b': (0.25, 3.0)}, 'a') == []
    assert len(placement_failures({'a': (0.0, 0.0), 'b': (0.2, 2.0)}, 'a', limits=(0.1, 5.0))) == 1
