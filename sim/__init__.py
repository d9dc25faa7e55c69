"""The simulator: a configured arm's physics (`plant`) behind the same wires a real arm speaks —
Dynamixel servos answering packets (`dynamixel`), CAN motors answering frames (`can`) — put where a
host reaches them (`transport`: pseudo-terminals, python-can's virtual bus, an SLCAN adapter).
`robot` builds one for any configuration, `lab` stands it on a bench as it arrives for bring-up,
and `faults` corrupts its wire for the soak and the tests."""
