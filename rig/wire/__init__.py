"""What goes over the bus and the port: the CAN messages (through the DBC), their bus
load, and the mass sensor's serial frame. Pure codecs: no threads, no clock."""
