"""The Allan variance of a whole record in chunks equals allantools' on the whole segments (issue 26)."""

import numpy as np

from stableins.estimators.allan import allan_points
from stableins.estimators.streaming_allan import StreamingAllan, octave_clusters


def test_chunks_and_gaps_give_allantools_pooled_points():
    rng = np.random.default_rng(1)
    first = rng.normal(size=(5000, 3))
    second = rng.normal(size=(3000, 3)) + 0.01 * np.cumsum(rng.normal(size=(3000, 3)), axis=0)
    reference = allan_points([first, second], 100.0, max_fraction=8)
    stream = StreamingAllan(reference.cluster, 100.0)
    for chunk in np.array_split(first, 7):
        stream.add(chunk)
    stream.gap()
    for chunk in np.array_split(second, 13):  # chunks shorter than the largest cluster too
        stream.add(chunk)
    points = stream.points()
    np.testing.assert_allclose(points.variance, reference.variance, rtol=1e-12)
    np.testing.assert_array_equal(points.terms, reference.terms)
    for mine, theirs in zip(points.segment_lengths, reference.segment_lengths, strict=True):
        np.testing.assert_array_equal(mine, theirs)


def test_octave_clusters():
    np.testing.assert_array_equal(octave_clusters(64, max_fraction=8), [1, 2, 4, 8])
    np.testing.assert_array_equal(octave_clusters(3), [1])
