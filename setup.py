"""Install the dxl_servo_driver ament_python package."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = 'dxl_servo_driver'

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(include=[PACKAGE, PACKAGE + '.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
        ('share/' + PACKAGE + '/config', glob('config/*.yaml')),
        ('share/' + PACKAGE + '/config/moveit', glob('config/moveit/*')),
        ('share/' + PACKAGE + '/launch', glob('launch/*.launch.py')),
        ('share/' + PACKAGE + '/udev', glob('udev/*.rules')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='dxl_servo_driver maintainers',
    maintainer_email='maintainers@dxl-servo-driver.org',
    description='ROS 2 driver and byte-level simulator for Dynamixel servos (every family, '
                'Protocol 1.0 and 2.0).',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'node = dxl_servo_driver.ros.main:main',
            'scan = dxl_servo_driver.tool.scan:main',
            'dxl = dxl_servo_driver.tool.main:main',
            'virtual_bus = dxl_servo_driver.sim.virtual_bus:main',
        ],
    },
)
