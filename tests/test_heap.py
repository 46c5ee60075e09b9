"""runtime.heap: start-up's objects frozen, young collections spaced out, a disabled one left off."""

from __future__ import annotations

import gc

from runtime.heap import YOUNG_THRESHOLD, freeze_startup


def test_freezing_start_up_spaces_young_collections_and_keeps_the_older_thresholds() -> None:
    before = gc.get_threshold()
    try:
        gc.set_threshold(700, 10, 10)
        freeze_startup()
        assert gc.get_threshold() == (YOUNG_THRESHOLD, 10, 10)
        assert gc.get_freeze_count() > 0
        gc.set_threshold(0, 10, 10)  # a collector switched off stays off
        freeze_startup()
        assert gc.get_threshold()[0] == 0
    finally:
        gc.unfreeze()
        gc.set_threshold(*before)
