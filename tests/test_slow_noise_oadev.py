"""Issue 30: the dwell test's Allan deviations and kernel convolution without allantools or scipy.signal, equal to the bit.

Both libraries import :mod:`scipy.stats` (about a second of every device command on a shared machine); the device path
now computes the same numbers itself (:func:`stableins.estimators.slow_noise.overlapping_allan_deviation`,
``_fftconvolve``).  These tests compare them with the libraries they replace, bit for bit.
"""

import subprocess
import sys

import allantools
import numpy as np
import pytest
from scipy.signal import fftconvolve

from stableins.estimators.slow_noise import _fftconvolve, dwell_test_clusters, overlapping_allan_deviation


@pytest.mark.parametrize(("n", "rate"), [(40, 1.0), (601, 10.0), (3000, 100.0), (12007, 99.7), (5, 3.0)])
def test_overlapping_allan_deviation_is_allantools_oadev_to_the_bit(n, rate):
    rng = np.random.default_rng(n)
    x = (9.8 + 1e-3 * rng.standard_normal((n, 3))).cumsum(axis=0) * 1e-3 + rng.standard_normal((n, 3))
    clusters = np.array(dwell_test_clusters(n) or (1, 2))
    for a in range(3):  # a strided column, as the dwell test passes it
        taus, devs = overlapping_allan_deviation(x[:, a], rate, clusters)
        expected_taus, expected_devs, _, _ = allantools.oadev(x[:, a], rate=rate, data_type="freq", taus=clusters / rate)
        np.testing.assert_array_equal(taus, expected_taus)
        np.testing.assert_array_equal(devs, expected_devs)


@pytest.mark.parametrize(("mi", "mj"), [(2, 2), (3, 7), (150, 75), (1000, 31)])
def test_the_kernel_convolution_is_scipy_fftconvolve_to_the_bit(mi, mj):
    hi = np.r_[-np.ones(mi), np.ones(mi)] / mi
    hj = np.r_[-np.ones(mj), np.ones(mj)] / mj
    np.testing.assert_array_equal(_fftconvolve(hi, hj[::-1]), fftconvolve(hi, hj[::-1], mode="full"))


def test_the_device_estimators_do_not_import_scipy_stats():
    """A device calibration's dwell summaries and noise model import neither scipy.stats nor allantools."""
    code = (
        "import sys, numpy as np\n"
        "from stableins.estimators.dwell import summarize_dwell\n"
        "from stableins.estimators.device import noise_from_dwells\n"
        "rng = np.random.default_rng(1)\n"
        "dwells = [summarize_dwell(np.arange(600) / 10, [0, 0, 9.8] + 1e-4 * rng.standard_normal((600, 3)), np.zeros((600, 3)),\n"
        "                          np.zeros(3), position=k) for k in (1, 2)]\n"
        "assert noise_from_dwells(dwells) is not None\n"
        "print(sorted(m for m in sys.modules if m.startswith(('scipy.stats', 'allantools', 'scipy.signal'))))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "[]"
