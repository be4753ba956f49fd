"""Thin rclpy nodes: parameters, message conversion, core calls, diagnostics."""
