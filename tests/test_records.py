"""The measurement records' unchecked constructor gives the record the checked one does."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from swarm_core.records import CameraRecord, LidarRecord, OdometryRecord, RobotMeasurements


def _read_only(*shape: int) -> np.ndarray:
    a = np.arange(float(np.prod(shape))).reshape(shape)
    a.setflags(write=False)
    return a


@pytest.mark.parametrize(
    "cls, values",
    [
        (OdometryRecord, (0.5, _read_only(3), _read_only(2))),
        (
            LidarRecord,
            (1.0, _read_only(4), _read_only(4), _read_only(4), _read_only(2, 2), _read_only(1)),
        ),
        (CameraRecord, (1.5, _read_only(3))),
        (RobotMeasurements, ([], [], [])),
    ],
)
def test_make_fills_every_field_in_order_as_the_constructor_does(cls, values):
    made, checked = cls._make(*values), cls(*values)
    assert type(made) is cls
    for field, value in zip(dataclasses.fields(cls), values, strict=True):
        got = getattr(made, field.name)
        assert got is value  # no copy on the hot path
        if isinstance(value, np.ndarray):
            np.testing.assert_array_equal(got, getattr(checked, field.name))
        else:
            assert got == getattr(checked, field.name)
