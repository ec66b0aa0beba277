"""World files in and out: the schema a world file is checked against, occupancy maps users bring
(ROS, images, MovingAI), and the one place file units become steps and back."""
