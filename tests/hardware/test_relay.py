"""`qz lcm-relay`: LCM's tcpq:// provider between processes on this machine, through 127.0.0.1.

The relay runs as its own process (as users run it): LCM's tcpq client connects from inside
DrakeLcm's constructor and would wait forever on a relay thread of the same interpreter.
"""

import json
import socket
import struct
import subprocess
import sys
import time

import pytest
from pydrake.lcm import DrakeLcm

from qz_drake.errors import ConfigError
from qz_drake.hardware.relay import MAGIC_CLIENT, PROTOCOL_VERSION, connect_lcm


def qz(*args) -> list[str]:
    return [sys.executable, "-m", "qz_drake.cli", *args]


@pytest.fixture
def relay():
    """A `qz lcm-relay --port 0` process: yields (url, process); stopped with SIGTERM."""
    process = subprocess.Popen(qz("lcm-relay", "--port", "0"), stdout=subprocess.PIPE, text=True)
    try:
        yield json.loads(process.stdout.readline())["lcm_url"], process
    finally:
        if process.poll() is None:
            process.terminate()
        process.wait(timeout=30)


def stop(process) -> dict:
    """Stops a relay and returns the counters it prints last."""
    process.terminate()
    return json.loads(process.communicate(timeout=30)[0].splitlines()[-1])


def receive(lcm: DrakeLcm, got: list, n: int, timeout: float = 5.0) -> None:
    end = time.monotonic() + timeout
    while len(got) < n and time.monotonic() < end:
        lcm.HandleSubscriptions(10)


def test_messages_go_to_the_subscribers_of_their_channel_only(relay):
    url, process = relay
    assert url.startswith("tcpq://127.0.0.1:")
    publisher, subscriber = connect_lcm(url), connect_lcm(url)
    status, other = [], []
    subscriber.Subscribe("QZ_STATUS", lambda data: status.append(bytes(data)))
    subscriber.Subscribe("QZ_POSE", lambda data: other.append(bytes(data)))
    time.sleep(0.2)  # the subscriptions reach the relay before the first message
    for k in range(100):
        publisher.Publish("QZ_STATUS", bytes([k]) * 500)
        publisher.Publish("QZ_COMMAND", b"not for this subscriber")
    receive(subscriber, status, 100)
    assert status == [bytes([k]) * 500 for k in range(100)] and other == []
    counters = stop(process)
    assert counters["relayed"] == 100 and counters["dropped"] == 0


def test_a_client_that_does_not_speak_lcm_is_dropped_and_the_others_carry_on(relay):
    url, process = relay
    port = int(url.rsplit(":", 1)[1])
    good_sender, good_receiver = connect_lcm(url), connect_lcm(url)
    got = []
    good_receiver.Subscribe("QZ_STATUS", lambda data: got.append(bytes(data)))
    with socket.create_connection(("127.0.0.1", port)) as stranger:
        stranger.sendall(b"GET / HTTP/1.1\r\n\r\n")
        assert stranger.recv(64)[:4] == struct.pack(">I", 0x287617FA)  # the relay's greeting, then
        stranger.settimeout(5.0)
        assert stranger.recv(64) == b""  # closed
    # A client that greets properly and then sends a frame of an unknown type fares the same.
    with socket.create_connection(("127.0.0.1", port)) as broken:
        broken.sendall(struct.pack(">III", MAGIC_CLIENT, PROTOCOL_VERSION, 99) + b"\0" * 8)
        broken.settimeout(5.0)
        while broken.recv(64):
            pass
    time.sleep(0.2)
    good_sender.Publish("QZ_STATUS", b"still relayed")
    receive(good_receiver, got, 1)
    assert got == [b"still relayed"]
    assert stop(process)["broken_clients"] == 2


def test_a_url_without_a_relay_or_a_busy_port_is_refused_in_one_line(relay):
    url, _ = relay
    port = int(url.rsplit(":", 1)[1])
    with socket.socket() as probe:  # a port that nothing listens on
        probe.bind(("127.0.0.1", 0))
        free = probe.getsockname()[1]
    with pytest.raises(ConfigError, match=rf"lcm_url = 'tcpq://127.0.0.1:{free}': no LCM relay answers there.*"
                                          rf"qz lcm-relay --port {free}"):
        connect_lcm(f"tcpq://127.0.0.1:{free}")
    busy = subprocess.run(qz("lcm-relay", "--port", str(port)), capture_output=True, text=True, timeout=60)
    assert busy.returncode == 2 and f"--port = {port}: cannot listen on 127.0.0.1:{port}" in busy.stderr
    assert busy.stderr.count("\n") == 1
    bad = subprocess.run(qz("lcm-relay", "--port", "70000"), capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "--port = 70000" in bad.stderr


def _nodelay_of_connections_to(port: int) -> list[int]:
    import os
    import stat

    flags = []
    for name in os.listdir("/proc/self/fd"):
        try:
            if not stat.S_ISSOCK(os.fstat(int(name)).st_mode):
                continue
            sock = socket.socket(fileno=os.dup(int(name)))
        except OSError:
            continue
        try:
            if sock.family == socket.AF_INET and sock.getpeername() == ("127.0.0.1", port):
                flags.append(sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY))
        except OSError:
            pass
        finally:
            sock.close()
    return flags


def test_a_client_sends_each_message_at_once(relay):
    # LCM's tcpq client writes a message in five sends; with Nagle's algorithm the last four
    # waited for the relay's (delayed) acknowledgement, and statuses sent on time arrived 22-30
    # ms late. connect_lcm turns Nagle's algorithm off on its connection to the relay.
    url, _ = relay
    port = int(url.rsplit(":", 1)[1])
    lcm = connect_lcm(url)
    flags = _nodelay_of_connections_to(port)
    assert len(flags) == 1 and flags[0] != 0
    second = connect_lcm(url)  # each connection of the process
    flags = _nodelay_of_connections_to(port)
    assert len(flags) == 2 and all(flags)
    del lcm, second
