"""The ROS 2 message types of the bags: the type store with the project's own messages registered."""

from __future__ import annotations

import functools
from importlib import resources

from rosbags.typesys import Stores, get_types_from_msg, get_typestore

__all__ = ["typestore", "MSG_TYPES"]

# project message types, defined by the .msg files beside this module
MSG_TYPES = {
    "nanosysid_msgs/msg/MotorTelemetry": "MotorTelemetry.msg",
    "nanosysid_msgs/msg/Status": "Status.msg",
}


@functools.lru_cache(maxsize=1)
def typestore():
    """ROS 2 Humble type store with the project's custom messages registered."""
    store = get_typestore(Stores.ROS2_HUMBLE)
    types = {}
    for name, file in MSG_TYPES.items():
        text = resources.files("nanosysid.bags").joinpath("msg", file).read_text()
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store
