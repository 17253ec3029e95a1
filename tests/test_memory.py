"""`keep_freed_memory`: a large block freed and allocated again is not faulted in again."""

import subprocess
import sys

import pytest

# Faults per 64 MB array allocated, written and freed, after a first one (a fresh process).
SCRIPT = """
import resource, sys
import numpy as np
from gae_jax.util.memory import keep_freed_memory
if sys.argv[1] == "keep" and not keep_freed_memory():
    sys.exit(3)
np.ones(1 << 23)
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(5):
    np.ones(1 << 23)
print((resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before) / 5)
"""


def faults(mode: str) -> float:
    done = subprocess.run([sys.executable, "-c", SCRIPT, mode], capture_output=True, text=True)
    if done.returncode == 3:
        pytest.skip("the C library has no mallopt (not glibc)")
    assert done.returncode == 0, done.stderr
    return float(done.stdout)


def test_a_freed_large_block_is_reused_without_faulting_it_in_again():
    default, kept = faults("default"), faults("keep")
    assert default >= 16  # 64 MB mapped afresh: at least one fault per 4 MB even in huge pages
    assert kept * 10 < default
