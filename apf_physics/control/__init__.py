"""Turning decisions into safe commands: the shield that keeps every chosen move clear
(``shield``), followers of a formation (``formation``), and unicycles driving holonomic plans
(``tracking``)."""
