"""A GNSS receiver for the ADCS stand, as a package of its own: the worked example of
``docs/adding_a_device_kind.md`` in the stand's repository.

- ``icd.toml``: the serial interface, the one file the codec, host and emulator are built on;
- :mod:`.codec`: datagrams <-> messages in SI units (the stand's ``drivers.datagram`` codec on this ICD);
- :mod:`.host`: :class:`~stand_gnss.host.GnssHost`, what flight software (or the stand) uses to read a receiver;
- :mod:`.emulator`: :class:`~stand_gnss.emulator.GnssEmulator`, the stand being the receiver;
- :mod:`.behaviour`: what the receiver measures: the truth's position and velocity with noise, and GPS time;
- :mod:`.kind`: the device kind the stand finds through the entry point ``adcs_stand.devices``.

The codec, host and emulator import nothing of ``stand`` or ``sim`` (as the stand's own ``drivers`` do not).
"""
