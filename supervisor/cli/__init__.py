"""The command line (uavbar-supervisor ...), the terminal client, the HPIPM installer."""
