"""One torch thread in these tests: the CI machine is small and shared, and multi-threaded LAPACK on
tiny matrices under load is far slower than a single thread."""
import pytest
import torch


@pytest.fixture(autouse=True)
def _one_thread():
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def _extra_missing() -> bool:
    import importlib.util

    return any(importlib.util.find_spec(m) is None for m in ("pytorch_lightning", "yaml", "matplotlib"))


if _extra_missing():          # the [experiments] extra is optional: nothing here can run without it
    collect_ignore_glob = ["test_*.py"]
