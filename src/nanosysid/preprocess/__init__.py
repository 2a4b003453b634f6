"""Preprocessing of the extracted tables into flights: one clock and one grid (:mod:`.sync`),
then gap filling and zero-phase filtering (:mod:`.filtering`). Reading and writing the bags
themselves is :mod:`nanosysid.bags`; the settings of the whole chain (extract, sync, filter)
are the ``preprocess`` config group."""

# the columns of each extracted stream beside its clocks ``t_recv`` and ``t_src``: what the extract
# stage writes (bags and rig logs alike) and the sync stage reads
STREAM_COLUMNS: dict[str, list[str]] = {
    "mocap": ["x", "y", "z", "qx", "qy", "qz", "qw"],
    "odom": ["x", "y", "z", "qx", "qy", "qz", "qw", "vx", "vy", "vz"],
    "imu": ["wx", "wy", "wz", "ax", "ay", "az"],
    "motors": ["m1", "m2", "m3", "m4"],
    "status": ["battery_voltage", "armed", "flying"],
    "setpoint": ["x", "y", "z", "yaw"],
}
