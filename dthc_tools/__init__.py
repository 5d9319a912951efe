"""Tools that run beside the daemon, never inside it: installed through extras.

    sender  the reference G-code sender (``dthc-bridge send``)          extra ``sender``
    demo    the whole stack end to end (``dthc-bridge demo``)            extra ``demo``
    bench   benchmark suites (``dthc-bridge bench SUITE``)              extra ``bench``
    sim     the daemon's controller service over a simulated board, in simulated time
            (the closed loop the benchmarks and the controller tests run)

Tools import the runtime (``dthc_bridge``), the wire format and the mock board; the runtime
never imports a tool (its command line finds them by name, see ``dthc_bridge.cli``).
"""
