"""The in-place row buffer of the nodes (``reducer_twin.nodes.buffers``)."""

import numpy as np
import pytest
from reducer_twin.nodes.buffers import RowBuffer

pytestmark = pytest.mark.timeout(30, method='thread')


def test_a_row_buffer_keeps_rows_in_order_across_growth_and_empties_on_take():
    buf = RowBuffer(3, capacity=4)
    rows = np.arange(30.0).reshape(10, 3)
    buf.extend(3)[:] = rows[:3]
    buf.extend(7)[:] = rows[3:]          # past the capacity: the buffer grows
    np.testing.assert_array_equal(buf.take(), rows)
    assert buf.n == 0 and buf.take().shape == (0, 3)
    buf.extend(2)[:] = rows[:2]
    taken = buf.take()
    buf.extend(2)[:] = -1.0               # reusing the space leaves the taken copy alone
    np.testing.assert_array_equal(taken, rows[:2])


def test_a_row_buffer_takes_single_rows_across_growth():
    buf = RowBuffer(3, capacity=2)
    rows = np.arange(15.0).reshape(5, 3)
    buf.extend(1)[:] = rows[:1]
    for row in rows[1:]:
        buf.append(row.tolist())        # the third row is past the capacity
    np.testing.assert_array_equal(buf.take(), rows)
