"""The system structures of Fig. 7 (.ssd) and their parameter sets (.ssv): data, installed with the package."""
