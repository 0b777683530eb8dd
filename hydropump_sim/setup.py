from setuptools import find_packages, setup

package_name = 'hydropump_sim'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools', 'numpy', 'scipy', 'numba', 'control', 'PyYAML',
                      'matplotlib'],
    zip_safe=False,
    maintainer='hydropump developers',
    maintainer_email='dev@hydropump.invalid',
    description='Plant library of an electro-hydraulic variable-displacement pump',
    license='Apache-2.0',
)
