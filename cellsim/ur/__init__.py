"""Universal Robots controllers: RTDE on the wire, the program's registers, an emulated controller."""
