# headless_map.py is a MAVProxy module the tests load (it needs MAVProxy and OpenCV), not a test
# module: --doctest-modules would import it where neither is installed
collect_ignore = ["headless_map.py"]
