"""Post-flight processing (``subpix process``, ``subpix report``): flight bags through the ROS-free
stage pipeline into products and a flight report, without DDS."""
