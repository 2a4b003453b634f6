"""Deprecated name of :mod:`nanosysid.campaign` (and of its ``HiddenWorld`` as ``World``), kept
for one release."""

import warnings

from nanosysid.campaign import *  # noqa: F401,F403
from nanosysid.campaign import HiddenWorld as World  # noqa: F401

warnings.warn("nanosysid.worlds is now nanosysid.campaign (and worlds.World is campaign.HiddenWorld); the old "
              "names go in the next release", DeprecationWarning, stacklevel=2)
