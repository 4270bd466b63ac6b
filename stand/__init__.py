"""The stand: the only package that composes the others.

Scenario files and validation, composition (build only what the scene needs), the multi-rate
loop and pacing, reference ADCS controllers and the plug-in API, recording, reports, command line.
"""
