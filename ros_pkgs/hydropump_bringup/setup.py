from glob import glob

from setuptools import setup

package_name = 'hydropump_bringup'

setup(
    name=package_name,
    version='0.1.0',
    packages=[],
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/launch', glob('launch/*.launch.py')),
        # config is a link to the repository's config/, the one source of the parameters.
        ('share/' + package_name + '/config', glob('config/*.yaml') + glob('config/*.xml')),
        ('share/' + package_name + '/config/circuits', glob('config/circuits/*.yaml')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='hydropump developers',
    maintainer_email='dev@hydropump.invalid',
    description='Launch files and parameter files of the hydropump suite',
    license='Apache-2.0',
)
