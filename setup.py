"""ament_python build of moseg_ros; the same file serves `pip install .` and `colcon build`."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "moseg_ros"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(include=[PACKAGE, f"{PACKAGE}.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*")),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
    ],
    python_requires=">=3.10",
    install_requires=["numpy>=1.24", "scipy>=1.10", "opencv-python-headless>=4.8", "rosbags>=0.10", "mcap>=1.1",
                      "threadpoolctl>=3.1", "pillow>=9", "PyYAML>=6"],
    # `moseg process --ray`, `moseg bench fleet`; `moseg eval map`
    extras_require={"fleet": ["ray>=2.40"], "map": ["pycolmap>=4.1", "evo>=1.30"]},
    zip_safe=True,
    maintainer="moseg_ros developers",
    maintainer_email="moseg-ros@example.org",
    description="Object-level motion segmentation from a moving monocular camera, as a ROS 2 node.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            f"segmenter = {PACKAGE}.node:main",
            f"moseg = {PACKAGE}.cli:main",
        ],
    },
)
