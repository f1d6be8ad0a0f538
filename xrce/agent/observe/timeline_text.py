"""A recovery timeline (xrce.agent.engine.timeline) as one line of text, for the agent's log and
``xrce-agent stats``: the engine records the timeline, what shows it formats it here, a floor below
both."""

from __future__ import annotations

from typing import Any, Dict, Optional


def _seconds(value: Optional[float]) -> str:
    return "-" if value is None else "+%.3f s" % value


def format_timeline(t: Dict[str, Any]) -> str:
    """One line for the log and the stats view, from ``Timeline.as_dict()``."""
    return ("client %s recovery timeline (%s): first datagram %s, session established %s, "
            "entities re-created %s (%d), READ_DATAs restored %s (%d), first sample into ROS %s"
            % (t["key"], t["cause"], _seconds(t["first_datagram_s"]),
               _seconds(t["session_established_s"]), _seconds(t["entities_recreated_s"]),
               t["entities"], _seconds(t["read_data_restored_s"]), t["read_datas"],
               _seconds(t["first_sample_to_ros_s"])))
