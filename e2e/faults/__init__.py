"""Fault injection on the bed (issue 37): what each fault cost, recorded and rendered."""
