"""Shared pytest set-up.

The Hugging Face Hub is made unreachable for the whole suite: lerobot silently falls
back to the Hub when a local dataset is missing or inconsistent, and a test must fail
loudly then instead of passing by download (or hanging).
"""

import os

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("HF_DATASETS_OFFLINE", "1")
os.environ.setdefault("MPLBACKEND", "Agg")
