"""One run on the table: the schedule of timed CAN messages, the receive threads, the
recorder that decodes into the run file, its clock fit and interlocks, the live status
and e-stop, the safe state, and the simulated rig's process. `runner.run_profile` is
the entry point."""
