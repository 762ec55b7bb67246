from glob import glob

from setuptools import find_packages, setup

package_name = 'darces_matcher'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
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
        '2D DARCES matching of Local onto Global ROI networks: library, node, evaluation CLI.'
    ),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'darces_eval = darces_matcher.eval_cli:main',
            'darces_matcher = darces_matcher.matcher_node:main',
        ],
    },
)
