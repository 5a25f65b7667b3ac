from setuptools import setup

PACKAGE = "swarm_phd_camera"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=[PACKAGE],
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", ["config/front.example.yaml", "config/back.example.yaml"]),
        (f"share/{PACKAGE}/launch", ["launch/camera.launch.py"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="swarm-phd contributors",
    maintainer_email="swarm-phd@users.noreply.github.com",
    description="Red-strip bearings from the two fisheye cameras (swarm_phd_msgs/BearingsStamped)",
    license="MIT",
    entry_points={"console_scripts": [f"camera_node = {PACKAGE}.camera_node:main"]},
)
