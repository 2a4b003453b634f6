"""Deprecated name of :mod:`nanosysid.preprocess.sync`, kept for one release."""

import warnings

from nanosysid.preprocess.sync import *  # noqa: F401,F403

warnings.warn("nanosysid.bags.sync is now nanosysid.preprocess.sync; the old name goes in the next release",
              DeprecationWarning, stacklevel=2)
