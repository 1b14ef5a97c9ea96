"""What the user configures: configuration files, rule profiles and the network
description."""
