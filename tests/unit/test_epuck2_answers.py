"""The e-puck2 driver's reading of the robot's byte stream: whole answers only, however TCP splits them."""

from __future__ import annotations

import pytest

from hardware.epuck2 import ANSWER_SIZES, EMPTY_ID, IMAGE_ID, SENSORS_ID, take_answers


def test_answers_split_anywhere_come_out_whole_once_and_in_order():
    sensors = bytes(range(ANSWER_SIZES[SENSORS_ID]))
    image = bytes([7]) * ANSWER_SIZES[IMAGE_ID]
    stream = bytes([SENSORS_ID]) + sensors + bytes([EMPTY_ID]) + bytes([IMAGE_ID]) + image
    for cut in (1, 2, 50, 105, 106, 107, 5000, len(stream) - 1):  # inside an id, a payload, between answers
        buffer, answers = bytearray(), []
        for piece in (stream[:cut], stream[cut:]):
            buffer += piece
            answers += take_answers(buffer)
        assert answers == [(SENSORS_ID, sensors), (EMPTY_ID, b""), (IMAGE_ID, image)], cut
        assert buffer == b""


def test_a_partial_answer_waits_in_the_buffer():
    buffer = bytearray([SENSORS_ID]) + bytes(10)
    assert take_answers(buffer) == []
    assert len(buffer) == 11


def test_an_unknown_answer_id_drops_the_connection():
    buffer = bytearray([EMPTY_ID, 0x42, 0, 0])
    with pytest.raises(ConnectionError, match="unknown answer id 0x42"):
        take_answers(buffer)
