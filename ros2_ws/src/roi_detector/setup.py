from glob import glob

from setuptools import find_packages, setup

package_name = 'roi_detector'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml')),
        ('share/' + package_name + '/models', glob('roi_detector/models/*.npz')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='globloc developers',
    maintainer_email='dev@globloc.invalid',
    description=(
        'ROI detection and classification (orbital and rover imagery), roi_detector and ln_builder nodes.'
    ),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            # roi_detector: the offline CLI (train, ln, eval) and, run with no
            # sub-command (as globloc run does), the roi_detector node.
            'roi_detector = roi_detector.cli:main',
            'ln_builder = roi_detector.ln_builder_node:main',
        ],
    },
)
