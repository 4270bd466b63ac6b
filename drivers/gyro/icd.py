"""The human-readable gyro ICD, rendered from ``fixtures/devices/gyro.toml``.

    python -m drivers.gyro.icd > docs/gyro_icd.md

A test checks that ``docs/gyro_icd.md`` equals :func:`render` of the fixture.
"""

from __future__ import annotations

from drivers.datagram import render_icd
from drivers.gyro.codec import GyroCodec

__all__ = ["render"]


def render(codec: GyroCodec | None = None) -> str:
    """The ICD as Markdown."""
    return render_icd(
        codec if codec is not None else GyroCodec(),
        title="Gyro serial interface (ICD)",
        source="fixtures/devices/gyro.toml",
        generator="drivers.gyro.icd",
        intro="Our own interface, modelled on the normal-mode datagram of the Safran STIM210/STIM300 gyro "
        "modules (identifier byte, 24-bit big-endian rates at 2^-14 deg/s, status, sample counter, latency, "
        "CRC; see the provenance comment in the TOML), with a device time stamp added. Host = the flight "
        "computer or the stand; device = the gyro or its emulator.",
        exchanges=[
            "The device streams RATE unasked every output period (default 10 ms, 100 Hz), from power-up; "
            "the sample counter steps by one per sample, so a gap tells the host how many were lost.",
            "RATE time stamp: the sample time in the device clock, which counts microseconds from power-up "
            "until SET_TIME sets it; from then on the status bit time_synced is set.",
            "valid is cleared while the device starts up and when any axis saturates (the rate is then "
            "clipped to the range of the field and that axis's saturated bit is set).",
            "SET_OUTPUT_PERIOD changes the output period from the next sample on; the first sample at the "
            "new period follows one new period after the command.",
            "Commands are not acknowledged (the device only streams); a command datagram with a bad CRC or "
            "a value outside its range is counted and ignored.",
        ],
    )


if __name__ == "__main__":  # pragma: no cover
    import sys

    sys.stdout.write(render())
