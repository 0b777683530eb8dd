"""FMI: the suite's circuits as FMUs (FMI 2.0 and 3.0 co-simulation, through PythonFMU and
PythonFMU3), checked with FMPy; a user's FMU run and calibrated. Nothing here is imported by
the rest of the suite: it needs ``pythonfmu`` (``pythonfmu3``) and ``fmpy`` only when an
FMU is built or read."""
