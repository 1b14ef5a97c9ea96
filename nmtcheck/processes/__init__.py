"""What is reconstructed across frames, once per input, for the rules to read: SDO
transfers, the configuration they wrote, and the CiA 302-2 boot-slave processes."""
