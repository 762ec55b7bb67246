from glob import glob

from setuptools import find_packages, setup

package_name = 'rover_bringup'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml') + glob('config/*.xml')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='globloc developers',
    maintainer_email='dev@globloc.invalid',
    description=(
        'Graph launcher, bag player, output recorder, parameters and evaluation (the globloc command).'
    ),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'globloc = rover_bringup.cli:main',
        ],
    },
)
