"""Post-flight processing (``subpix process``, ``subpix report``), without DDS.

Flight bags go through the ROS-free stage pipeline into products and a flight report.
"""
