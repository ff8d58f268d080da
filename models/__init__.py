"""Pure numerics of near-field acoustic levitation: no FMI, no ports, no result files."""
