"""LinuxCNC's plasmac component as a controller of ``bench control``, in this process.

- :mod:`.fetch`: the component from Debian's ``linuxcnc-uspace`` (downloaded with apt into
  a cache, unpacked, not installed) and our HAL shim (``hal_shim.c``) built with ``cc``;
- :mod:`.component`: a private copy of ``plasmac.so`` per run, its pins, one call a period;
- :mod:`.motion`: LinuxCNC's external-offset planner and ``dbounce``, emulated;
- :mod:`.host`: the component in closed loop with our ``Plant``, a whole program per run;
- :mod:`.halrun`: the proof, a recorded run replayed into LinuxCNC's own runtime.
"""
