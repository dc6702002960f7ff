"""deterministic_training: the fixed thread count and deterministic algorithms of every
gear fit, and the caller's settings restored afterwards."""

import pytest
import torch
from threadpoolctl import threadpool_info

from dynoplan.models.trainer import TRAINING_THREADS, deterministic_training


def _blas_threads() -> list[int]:
    return [pool["num_threads"] for pool in threadpool_info()]


def test_inside_one_thread_and_deterministic_algorithms_outside_the_callers_settings():
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        torch.use_deterministic_algorithms(False)
        pools = _blas_threads()
        with deterministic_training():
            assert torch.get_num_threads() == TRAINING_THREADS == 1
            assert torch.are_deterministic_algorithms_enabled()
            assert all(n == 1 for n in _blas_threads())
        assert torch.get_num_threads() == 2
        assert not torch.are_deterministic_algorithms_enabled()
        assert _blas_threads() == pools
    finally:
        torch.set_num_threads(before)


def test_settings_are_restored_when_the_fit_raises():
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        torch.use_deterministic_algorithms(True, warn_only=True)
        with pytest.raises(RuntimeError, match="boom"), deterministic_training():
            assert not torch.is_deterministic_algorithms_warn_only_enabled()
            raise RuntimeError("boom")
        assert torch.get_num_threads() == 2
        assert torch.are_deterministic_algorithms_enabled()
        assert torch.is_deterministic_algorithms_warn_only_enabled()
    finally:
        torch.use_deterministic_algorithms(False)
        torch.set_num_threads(before)


def test_a_thread_count_below_one_is_rejected():
    with pytest.raises(ValueError, match="threads"), deterministic_training(0):
        pass
