from setuptools import find_packages, setup

package_name = "msgs_py"

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
    description="Conversions between climb_msgs messages and climb_core dataclasses.",
    license="Apache-2.0",
    entry_points={"console_scripts": []},
)
