from setuptools import find_packages, setup

package_name = "climb_coordinator"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/launch", ["launch/climb.launch.py"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    description="Climb orchestration: plan, execute in the simulator, record.",
    license="Apache-2.0",
    entry_points={"console_scripts": ["sim_graph = climb_coordinator.sim_graph:main",
                                        "recorder = climb_coordinator.entry:recorder",
                                        "climb_coordinator = climb_coordinator.entry:coordinator"]},
)
