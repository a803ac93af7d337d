"""The fast closed-loop simulator and the scenarios that script it."""
