"""Fault injection for the mapper process (tests/slam/run/test_mapper_faults.py puts this folder first on PYTHONPATH,
so every interpreter of the test's run imports it, the spawned mapping process too).

``LRSLAM_TEST_FAULT=raise:K``: the mapping call of frame position K raises inside the mapping process.
``LRSLAM_TEST_FAULT=cut:K``: the mapping process sends half of that call's reply (its map), then kills itself: a
death in the middle of the map's handover. Nothing happens in any other process (the parent rehearses and maps
inline under other names), nor without the variable."""

import os

_FAULT = os.environ.get("LRSLAM_TEST_FAULT", "")

if _FAULT:
    import multiprocessing
    import multiprocessing.connection
    import signal
    import struct

    import slam.engine.mapper as _mapper

    _kind, _at = _FAULT.split(":")
    _at = int(_at)
    _real_map = _mapper.map_frame
    _real_send = multiprocessing.connection.Connection.send_bytes
    _armed = []

    def _in_child() -> bool:
        return multiprocessing.current_process().name == "lrslam-map"

    def map_frame(scene, index, *args, **kwargs):
        if _in_child() and index == _at:
            if _kind == "raise":
                raise FloatingPointError(f"injected fault in the mapping call of frame {index}")
            _armed.append(index)
        return _real_map(scene, index, *args, **kwargs)

    def send_bytes(self, buf, offset=0, size=None):
        if _armed and _in_child():
            data = bytes(memoryview(buf)[offset:None if size is None else offset + size])
            self._send(struct.pack("!i", len(data)) + data[: len(data) // 2])  # half of the message, then death
            os.kill(os.getpid(), signal.SIGKILL)
        return _real_send(self, buf, offset, size)

    _mapper.map_frame = map_frame
    multiprocessing.connection.Connection.send_bytes = send_bytes
