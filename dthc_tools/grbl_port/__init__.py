"""A grbl 1.1 for any grbl sender (CNCjs, UGS, gSender, bCNC) in front of the table's own
grbl and the daemon (issue 32): the pieces built so far.

- :mod:`.receiver`: what a sender writes, split as grbl's serial receiver splits it
  (real-time bytes at once, lines in order, one answer each).
"""
