"""Real hardware: Dynamixel servo bus, light controllers, cameras. Imports nothing of gonio's
other packages (the bottom layer); :mod:`drivers.errors` is the shared exception hierarchy."""
