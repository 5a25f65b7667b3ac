from setuptools import setup

PACKAGE = "swarm_phd_onboard"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=[PACKAGE],
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="swarm-phd contributors",
    maintainer_email="swarm-phd@users.noreply.github.com",
    description="One robot's localizer on board (swarm_phd_msgs/EstimateStamped)",
    license="MIT",
    entry_points={"console_scripts": [f"onboard_filter = {PACKAGE}.onboard_node:main"]},
)
