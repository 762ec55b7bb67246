from glob import glob

from setuptools import find_packages, setup

package_name = 'orbital_gn'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    # The committed default model (npz + JSON provenance, no pickle).
    package_data={package_name: ['models/*.npz', 'models/*.json']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='globloc developers',
    maintainer_email='dev@globloc.invalid',
    description=(
        'Offline Global Network preparation from a georeferenced orthoimage, and the gn_server node.'
    ),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'orbital_gn = orbital_gn.cli:main',
            'gn_server = orbital_gn.gn_server:main',
        ],
    },
)
