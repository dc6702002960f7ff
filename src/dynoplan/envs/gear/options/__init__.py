"""The paper's four options of the gear assembly and their starting states."""
