from setuptools import find_packages, setup

package_name = 'hydropump_ctrl'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools', 'hydropump_sim', 'numpy', 'scipy', 'rosbags', 'mcap',
                      'mcap-ros2-support', 'tqdm'],
    zip_safe=False,
    maintainer='hydropump developers',
    maintainer_email='dev@hydropump.invalid',
    description='Control and identification for the hydropump plant',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'hydropump = hydropump_ctrl.cli:main',
        ],
    },
)
