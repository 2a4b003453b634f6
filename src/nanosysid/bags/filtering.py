"""Deprecated name of :mod:`nanosysid.preprocess.filtering`, kept for one release."""

import warnings

from nanosysid.preprocess.filtering import *  # noqa: F401,F403

warnings.warn("nanosysid.bags.filtering is now nanosysid.preprocess.filtering; the old name goes in the next release",
              DeprecationWarning, stacklevel=2)
