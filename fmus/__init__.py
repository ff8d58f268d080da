"""FMI 2.0 co-simulation slaves (pythonfmu), one per file, thin adapters over nfal.models; and their build."""
