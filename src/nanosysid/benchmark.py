"""Deprecated name of :mod:`nanosysid.protocol`, kept for one release."""

import warnings

from nanosysid.protocol import *  # noqa: F401,F403

warnings.warn("nanosysid.benchmark is now nanosysid.protocol; the old name goes in the next release",
              DeprecationWarning, stacklevel=2)
