from setuptools import find_packages, setup

package_name = "planner_node"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    description="Guide path, contact search, physics-constrained IK, motion primitives and their adaptation: library + nodes.",
    license="Apache-2.0",
    entry_points={"console_scripts": [
        "guide_path = planner_node.guide_path_node:main",
        "contact_search = planner_node.contact_search_node:main",
        "primitive_adaptation = planner_node.adaptation_node:main",
    ]},
)
