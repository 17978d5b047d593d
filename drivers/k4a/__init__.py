"""Azure Kinect and Orbbec Femto: Matroska recordings and the lens model."""
