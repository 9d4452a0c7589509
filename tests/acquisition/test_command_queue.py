"""What a source applies between blocks (``acquisition/command_queue.py``), on the simulated rig's
source and on the queue itself: a flood is refused as busy at MAX_PENDING_COMMANDS instead of growing
without bound (100 000 queued commands held an emulated bench's output on for 72 s after an
acknowledged off, and its log lost 18 s); output off goes out at once, in the caller's thread, and
cancels the ``output on`` queued before it; after close nothing is applied, and a command in flight
finishes before the close's off, never after it (a shutdown under a flood switched the output back
on 65 ms after the bench's safe off).  No test here waits on time: each waits on the event it needs."""

from __future__ import annotations

import threading

import pytest

from hystbench.acquisition.command_queue import MAX_PENDING_COMMANDS, CommandQueue
from hystbench.acquisition.sources import RigSource
from hystbench.errors import CommandRefused
from hystbench.sim_backend.rig import SimulatedRig

HANG_S = 60.0  # what a wait may take only if the code under test hangs


def _source() -> RigSource:
    rig = SimulatedRig("voicecoil_ferrite", frequency_hz=320.0)
    rig.output_enabled = False
    return RigSource(rig, block_samples=100, pace="max", max_current_a=2.0)


def test_a_flood_is_refused_as_busy_at_the_bound_and_taken_again_once_applied():
    src = _source()
    for k in range(MAX_PENDING_COMMANDS):
        src.set_excitation(current_pp_a=0.001 * (k + 1))
    with pytest.raises(CommandRefused, match=rf"busy, {MAX_PENDING_COMMANDS} commands are waiting"):
        src.set_excitation(current_pp_a=0.5)
    with pytest.raises(CommandRefused, match="busy"):
        src.set_output(True)
    src.set_output(False)  # never refused
    next(iter(src.blocks()))  # the source's thread applies the queue between blocks
    assert src.rig.current_pp_a == pytest.approx(0.001 * MAX_PENDING_COMMANDS)  # in order, the last one last
    src.set_excitation(current_pp_a=0.5)
    src.close()


def test_output_off_goes_out_at_once_and_cancels_the_ons_queued_before_it():
    src = _source()
    src.set_output(True)
    src.set_excitation(current_pp_a=0.8)
    src.rig.output_enabled = True  # as if on already
    src.set_output(False)
    assert src.rig.output_enabled is False  # before any block: the off did not wait in the queue
    blocks = src.blocks()
    first = next(blocks)
    assert src.rig.output_enabled is False and not first.meta["output_on"]  # the earlier on was dropped
    assert src.rig.current_pp_a == pytest.approx(0.8)  # what else was queued is applied, in order
    src.set_output(True)  # an on after the off is a new intention
    next(blocks)
    assert src.rig.output_enabled is True
    src.close()
    assert src.rig.output_enabled is False


def test_after_close_nothing_queued_is_applied_and_nothing_more_is_taken():
    src = _source()
    src.set_excitation(current_pp_a=0.37)
    src.set_output(True)
    src.close()
    assert src._commands.apply() is False
    assert src.rig.output_enabled is False and src.rig.current_pp_a != pytest.approx(0.37)
    with pytest.raises(CommandRefused, match="closed"):
        src.set_output(True)


def test_a_command_in_flight_finishes_before_the_close_switches_the_output_off():
    log: list[str] = []
    started, release = threading.Event(), threading.Event()
    queue = CommandQueue("test bench", lambda: log.append("off"))

    def slow_on() -> None:  # an output-on whose round trips take a while
        started.set()
        release.wait(HANG_S)
        log.append("on")

    queue.put(slow_on, output_on=True)
    applier = threading.Thread(target=queue.apply)
    applier.start()
    assert started.wait(HANG_S)  # the bound is for a hang only
    closer = threading.Thread(target=queue.close)
    closer.start()
    release.set()
    applier.join(HANG_S)
    closer.join(HANG_S)
    assert log == ["on", "off"]
    assert queue.apply() is False



def test_what_comes_while_the_queue_is_applied_waits_for_the_next_block():
    """A command that arrives while the source applies the queue waits for the next turn: a client
    sending as fast as commands are applied would otherwise keep the source from its samples."""
    done: list[int] = []
    queue = CommandQueue("test bench", lambda: None)

    def command(k: int) -> None:
        done.append(k)
        if k < 3:
            queue.put(lambda: command(k + 10))  # a new command arrives as each is applied

    for k in range(3):
        queue.put(lambda k=k: command(k))
    assert queue.apply() is True and done == [0, 1, 2]  # the three queued when the turn began
    assert queue.apply() is True and done == [0, 1, 2, 10, 11, 12]
    assert queue.apply() is False
