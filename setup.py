"""pip install of the ROS-free core of aslip_ros (and the `aslip` command).

colcon ignores this file for the ament_cmake package; it exists so that `pip install .`
gives the scene, data, learning and control core without ROS. The generated message module
`aslip_ros.msg` only exists in a colcon build; the .msg sources ship as data so the core can
still read and write the project's messages in rosbags.
"""

from glob import glob

from setuptools import find_packages, setup

setup(
    name="aslip_ros",
    version="0.1.0",
    description="Acoustic in-hand slip sensing (A-SLIP) for ROS 2: ROS-free core",
    license="Apache-2.0",
    python_requires=">=3.10",
    packages=find_packages(include=["aslip_ros", "aslip_ros.*"]),
    data_files=[("share/aslip_ros/msg", sorted(glob("msg/*.msg")))],
    install_requires=[
        "numpy>=1.24",
        "scipy>=1.10",
        "torch>=2.2",
        "scikit-learn>=1.3",
        "rosbags>=0.10",
        "mcap>=1.1",
        "matplotlib>=3.7",
        "tqdm>=4.60",
        "PyYAML>=6",
    ],
    extras_require={"hw": ["sounddevice>=0.4", "xarm-python-sdk>=1.13"]},
    entry_points={"console_scripts": ["aslip = aslip_ros.cli:main"]},
)
