"""The human-readable reaction-wheel ICD, rendered from ``fixtures/devices/reaction_wheel.dbc``.

    python -m drivers.reaction_wheel.icd > docs/reaction_wheel_icd.md

A test checks that ``docs/reaction_wheel_icd.md`` equals :func:`render` of the fixture.
"""

from __future__ import annotations

from drivers.dbc_doc import render_dbc_icd
from drivers.reaction_wheel.codec import MAX_WHEELS, NODE_BASE, ReactionWheelCodec

__all__ = ["render"]


def render(codec: ReactionWheelCodec | None = None) -> str:
    """The ICD as Markdown."""
    c = codec if codec is not None else ReactionWheelCodec()
    return render_dbc_icd(
        c.dbc,
        title="Reaction wheel CAN interface (ICD)",
        source="fixtures/devices/reaction_wheel.dbc",
        generator="drivers.reaction_wheel.icd",
        intro="Our own interface, modelled on public smallsat wheel interfaces: the NSP wheels' torque and speed "
        "modes selected by which command is written (Sinclair/Rocket Lab RW-0.003 and RW4-12), the CubeSpace "
        "CubeWheel's speed telemetry, and the CANopen-like heartbeat of the stand's magnetorquer board. "
        "Host = the flight computer or the stand; RW = one wheel or its emulator.",
        id_note=f"One node per wheel: wheel n (0..{MAX_WHEELS - 1}) is node 0x{NODE_BASE:02X} + n and uses every "
        "id below plus n (the ids listed are wheel 0's), so up to sixteen wheels share one bus. A wheel "
        "ignores the other wheels' frames.",
        behaviour=[
            "RW_TORQUE_CMD selects mode TORQUE and holds the torque; RW_SPEED_CMD selects mode SPEED and the "
            "wheel's own controller drives the speed to the command; RW_MODE_CMD sets a mode with a zero "
            "command (IDLE: motor off, the wheel coasts down on its friction).",
            "The wheel clips a torque beyond its rating or a speed beyond its rated speed, keeping the sign, "
            "and counts a saturation; RW_SPEED_TLM.torque_limited tells the host the last torque was clipped.",
            "A command with timeout_ms > 0 is dropped that long after it unless a new command came, and the "
            "wheel goes IDLE (motor off, it coasts): a silent host cannot leave a wheel accelerating.",
            "Positive torque and speed are about the wheel's spin axis (the mounting gives its direction in "
            "the body); the body feels the opposite of the motor torque.",
            "RW_SPEED_TLM every 100 ms, RW_STATUS and RW_HEARTBEAT every 1000 ms (GenMsgCycleTime); the "
            "counters wrap at their widths and reset on RW_MODE_CMD.reset_counters; seq_ack echoes the seq "
            "of the last command applied.",
            "Frames with an id that is no wheel's, a wrong length or an undecodable value are counted and "
            "dropped, never answered.",
        ],
    )


if __name__ == "__main__":  # pragma: no cover
    import sys

    sys.stdout.write(render())
