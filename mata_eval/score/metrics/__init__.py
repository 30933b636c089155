"""Tracking metrics (paper section 3.3)."""

from .measures import *  # noqa: F401,F403
from .measures import PROFILES, get_profile  # noqa: F401
