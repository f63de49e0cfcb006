"""Progress bars on long work (tqdm), off where a caller asks for quiet output."""

from __future__ import annotations


def progress_bar(it, enabled: bool, desc: str):
    """``it`` wrapped in a tqdm bar when ``enabled``."""
    if not enabled:
        return it
    from tqdm.auto import tqdm

    return tqdm(it, desc=desc, leave=False, dynamic_ncols=True)
