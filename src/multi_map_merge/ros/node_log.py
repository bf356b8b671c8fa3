"""Lines the node logs about the merger's results (pure: no rospy)."""
from __future__ import annotations

from ..core.merger import REF_PARAMETER, REF_PROPOSED, ReferenceChoice


def reference_message(choice: ReferenceChoice) -> str:
    """The node's info line saying which robot is the reference (the merged frame is its map
    frame), why, and how to choose it (``~reference_robot``); '' before there is one."""
    ref = choice.robot
    if not ref:
        return ''
    if choice.why == REF_PARAMETER:
        return 'reference robot %s (set by ~reference_robot): the merged frame is its map frame' % ref
    if choice.why == REF_PROPOSED:
        return ('reference robot %s (the first of ~robots by name; set ~reference_robot to choose '
                'another): the merged frame is its map frame' % ref)
    others = ', '.join(choice.with_maps)
    if not choice.fixed:
        return ('reference robot %s for now (the first by name among the robots with a map: %s): the '
                'merged frame is its map frame; a robot of a lower name whose map comes before another '
                'robot is merged with %s takes it over; set ~reference_robot to fix it' % (ref, others, ref))
    return ('reference robot %s, fixed now that another robot is merged with it (it was the first by name '
            'among the robots with a map: %s; a robot whose map comes later does not take the merged '
            'frame over): set ~reference_robot: %s for the same merged frame in every run'
            % (ref, others, ref))
