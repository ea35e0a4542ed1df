"""Pure numpy/scipy/OpenCV motion core: geometry, motion models, affinities, clustering. Imports no ROS."""
