"""The FMI Reference FMUs the tests run (sources here, built by :func:`build.build_reference_fmus`)."""
