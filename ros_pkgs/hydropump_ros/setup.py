from setuptools import find_packages, setup

package_name = 'hydropump_ros'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools', 'hydropump_sim', 'hydropump_ctrl', 'rosbags', 'foxglove-sdk'],
    zip_safe=False,
    maintainer='hydropump developers',
    maintainer_email='dev@hydropump.invalid',
    description='ROS 2 nodes of the hydropump suite',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'simulator = hydropump_ros.entry:simulator',
            'controller = hydropump_ros.entry:controller',
            'recorder = hydropump_ros.entry:recorder',
            'foxglove = hydropump_ros.entry:foxglove',
            'hydropump-graph = hydropump_ros.graph:main',
            'hydropump-demo = hydropump_ros.campaign:main',
        ],
        # What the pure `hydropump` command runs through the node graph (it looks the
        # group up with importlib.metadata and never imports ROS itself).
        'hydropump.runners': [
            'record = hydropump_ros.record:run',
        ],
    },
)
