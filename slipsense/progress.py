"""Progress bars on long work (tqdm), off where a caller asks for quiet output."""

from __future__ import annotations

from tqdm.auto import tqdm


def progress_bar(it, enabled: bool, desc: str):
    """``it`` wrapped in a tqdm bar when ``enabled``."""
    if not enabled:
        return it

    return tqdm(it, desc=desc, leave=False, dynamic_ncols=True)
