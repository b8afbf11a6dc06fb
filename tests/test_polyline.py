"""igljoin.polyline: lengths and arc length on polylines with known answers."""

from __future__ import annotations

import numpy as np
import pytest

from igljoin.polyline import arc_length_parameters, mean_segment, polyline_length, segment_lengths

SQUARE = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
# segments 3, 4 and (closing) 5: a 3-4-5 right triangle
TRIANGLE = np.array([[0.0, 0.0], [3.0, 0.0], [3.0, 4.0]])


def test_segment_lengths_closed_and_open():
    np.testing.assert_array_equal(segment_lengths(TRIANGLE, True), [3.0, 4.0, 5.0])
    np.testing.assert_array_equal(segment_lengths(TRIANGLE, False), [3.0, 4.0])


def test_lengths_and_mean_segment():
    assert polyline_length(SQUARE) == 4.0  # closed by default
    assert polyline_length(SQUARE, False) == 3.0
    assert mean_segment(TRIANGLE, True) == 4.0
    assert mean_segment(TRIANGLE, False) == 3.5
    assert polyline_length(SQUARE[:1]) == 0.0  # a single point has no length


def test_arc_length_parameters():
    t, length = arc_length_parameters(TRIANGLE, True)
    assert length == 12.0
    # cumulative lengths 0, 3, 7 over the perimeter 12; sums of small integers are exact
    np.testing.assert_array_equal(t, [0.0, 0.25, 7.0 / 12.0])
    t, length = arc_length_parameters(TRIANGLE, False)
    assert length == 7.0 and t[-1] == 1.0
    assert t[1] == pytest.approx(3.0 / 7.0, rel=1e-15)  # one division: rounding only


def test_arc_length_of_a_point_repeated():
    t, length = arc_length_parameters(np.ones((3, 3)), False)
    assert length == 0.0 and not t.any()
