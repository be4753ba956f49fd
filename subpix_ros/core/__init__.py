"""The science: pure numpy/OpenCV, no ROS imports (one module per method)."""
