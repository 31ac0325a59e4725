"""Fault injection on the bed (issue 37): the fleets the fault tests run and what they read of
them, and what each fault cost, recorded and rendered."""
