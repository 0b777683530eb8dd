"""FMI: the suite's circuits as FMUs (FMI 2.0 co-simulation, through PythonFMU), checked
with FMPy. Nothing here is imported by the rest of the suite: it needs ``pythonfmu`` and
``fmpy`` only when an FMU is built or read."""
