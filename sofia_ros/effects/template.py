"""`sofia effects new NAME --kind KIND`: a plug-in module to fill in, one hook and its parameters.

The template is a working effect (its default parameter is zero, so it changes nothing until
given a value): the user replaces the one marked line with the physics the residual showed.
"""

from __future__ import annotations

import builtins
import importlib.util
import keyword
import re
from pathlib import Path

from sofia_ros.errors import ConfigError
from sofia_ros.output_files import atomic_output

__all__ = ['KINDS', 'plugin_template', 'write_plugin_template']

_HEADER = '''"""{name}: {summary}

Written by `sofia effects new {name} --kind {kind}`. Use it with

    SOFIA_EFFECT_MODULES={name} PYTHONPATH={folder} sofia compare BAG --model MODEL.yaml

then `sofia model add {name} --model MODEL.yaml` makes it a fitted term; a truth file may
carry it too (the simulator calls the same hook). The context's fields, frames and signs:
docs/discovery.md ("Plug-in hooks").
"""

import numpy as np

from sofia_ros.effects import EffectSpec, Parameter
'''

#: Longest plug-in name: its hook functions append up to 16 characters, and it names a file.
_MAX_NAME_CHARS = 64
#: ASCII only: Python folds other letters (NFKC) in an import, so the file name and the module would differ.
_MODULE_NAME = re.compile(rf'[a-z][a-z0-9_]{{0,{_MAX_NAME_CHARS - 1}}}')

#: kind -> (one-line summary, hook name, the hook's source, parameter line)
KINDS = {
    'camera': (
        'a shift of one camera\'s centroids on its detector',
        'camera_shift_px',
        '''

def {name}_shift_px(params, context):
    """Pixels (X, Y) added to each centroid of the FFI: here proportional to the elevation above 40 deg."""
    shift = np.zeros((len(context), 2))
    if context.camera == 'ffi':  # hipo, fpi, ffi or wfi
        # context: time_s, elevation_deg, temperature_c, specific_force_m_per_s2 (N, 3, TARF), los_angle_deg,
        # detector_x_px, detector_y_px, hip. Replace this line with the physics:
        shift[:, 1] = params['gain_arcsec_per_deg'] * (context.elevation_deg - 40.0) / 4.07  # FFI: 4.07"/px
    return shift
''',
        "Parameter('gain_arcsec_per_deg', 0.0, 'arcsec/deg', 'shift along rows per degree of elevation above 40')",
    ),
    'camera-rotation': (
        'a rotation of one camera\'s frame against TARF',
        'camera_rotation',
        '''

def {name}_rotation_arcsec(params, context):
    """Rotation (about EL, XEL, LOS) ["] of the FFI frame: here about XEL, with the temperature."""
    rotation = np.zeros((len(context), 3))
    if context.camera == 'ffi':  # hipo, fpi, ffi or wfi
        # context: time_s, elevation_deg, temperature_c, specific_force_m_per_s2 (N, 3, TARF), los_angle_deg.
        # +EL moves a star on the LOS to +Y rows, +XEL to -X columns. Replace this line with the physics:
        rotation[:, 1] = params['xel_arcsec_per_c'] * (context.temperature_c - 22.8)
    return rotation
''',
        "Parameter('xel_arcsec_per_c', 0.0, 'arcsec/C', 'rotation about XEL per degree C above 22.8')",
    ),
    'gyro': (
        'a rate every gyro axis reads on top of the true one',
        'gyro_rate_offset',
        '''

def {name}_rate_rad_per_s(params, context):
    """Rate (GYRF EL, XEL, LOS) [rad/s] the gyros read in addition: here a LOS bias with the specific force."""
    offsets = np.zeros((len(context), 3))
    # context: time_s, temperature_c, specific_force_m_per_s2 (N, 3, TARF), rates_rad_per_s (N, 3, GYRF).
    # Replace this line with the physics:
    g_along_los = context.specific_force_m_per_s2[:, 2] / 9.80665
    offsets[:, 2] = params['los_deg_per_h_per_g'] * g_along_los * np.pi / 180.0 / 3600.0
    return offsets
''',
        "Parameter('los_deg_per_h_per_g', 0.0, 'deg/h/g', 'LOS bias per g of specific force along the LOS')",
    ),
}

_FOOTER = '''

EFFECTS = (
    EffectSpec(
        {name!r}, 'plug-in', 'user plug-in',
        {summary!r},
        ({parameter},),
        {hook}={function},
    ),
)
'''


def plugin_template(name: str, kind: str, folder: str = '.') -> str:
    """The source of a plug-in module NAME of KIND; ConfigError for a name or kind that cannot work.

    Args:
        name: the module's name (a short lower-case identifier, shadowing nothing).
        kind: a key of KINDS.
        folder: the folder the module goes to, written into its docstring's usage line.

    Returns:
        The module's Python source.

    Raises:
        ConfigError: an unknown kind, an unusable name, or a folder that cannot be written into the source.
    """
    if kind not in KINDS:
        raise ConfigError(f'unknown plug-in kind {kind!r}; choose one of {", ".join(KINDS)}')
    _check_module_name(name)
    summary, hook, source, parameter = KINDS[kind]
    function = {'camera_shift_px': f'{name}_shift_px', 'camera_rotation': f'{name}_rotation_arcsec',
                'gyro_rate_offset': f'{name}_rate_rad_per_s'}[hook]
    text = (_HEADER.format(name=name, summary=summary, kind=kind, folder=folder) + source.format(name=name)
            + _FOOTER.format(name=name, summary=summary, parameter=parameter, hook=hook, function=function))
    # The folder is written into the docstring: bytes that are not UTF-8, a quote or a backslash break the module.
    try:
        compile(text.encode('utf-8'), f'{name}.py', 'exec')
    except UnicodeEncodeError as err:
        raise ConfigError(f'folder {folder!r} is not UTF-8 text; choose a --dir named in UTF-8') from err
    except SyntaxError as err:
        raise ConfigError(f'folder {folder!r} cannot be written into the template\'s docstring ({err.msg}); '
                          'choose a --dir without quotes or backslashes') from err
    return text


def _check_module_name(name):
    """ConfigError unless ``name`` can be a plug-in module: a short lower-case ASCII identifier that is no
    keyword, builtin or effect, and shadows no importable module.

    With its folder first on PYTHONPATH (as the template says), a plug-in named like an installed
    module (numpy, yaml, sofia_ros) would be imported in its place by every sofia command.
    """
    if not _MODULE_NAME.fullmatch(name):
        raise ConfigError(f'plug-in name {name[:_MAX_NAME_CHARS]!r} must be a lower-case Python identifier of at most '
                          f'{_MAX_NAME_CHARS} characters (a-z, 0-9, _; e.g. ffi_thermal_shift)')
    if keyword.iskeyword(name) or keyword.issoftkeyword(name) or hasattr(builtins, name):
        raise ConfigError(f'plug-in name {name!r} is a Python keyword or builtin; choose another name '
                          f'(e.g. {name}_effect)')
    from sofia_ros.effects import CATALOGUE

    if name in CATALOGUE:
        raise ConfigError(f'{name!r} is already an effect; choose another name')
    try:
        shadowed = importlib.util.find_spec(name) is not None
    except (ImportError, ValueError):  # a module already imported without a spec: taken all the same
        shadowed = True
    if shadowed:
        raise ConfigError(f'plug-in name {name!r} is the name of an importable module, which the plug-in would '
                          f'shadow on PYTHONPATH; choose another name (e.g. {name}_effect)')


def write_plugin_template(name: str, kind: str, directory: str | Path = '.') -> Path:
    """Write NAME.py into ``directory`` (which must exist; the file must not) whole or not at all; return its path.

    Args:
        name: the module's name (plugin_template).
        kind: a key of KINDS.
        directory: an existing folder.

    Returns:
        The path of the module written.

    Raises:
        ConfigError: the folder is missing, the file exists, or plugin_template refuses the name or kind.
    """
    if str(directory) == '':
        raise ConfigError('--dir is given an empty value; give a folder or leave --dir out')
    directory = Path(directory)
    if not directory.is_dir():
        what = 'is not a directory' if directory.exists() else 'does not exist'
        raise ConfigError(f'directory {directory} {what}; create it or give another --dir')
    data = plugin_template(name, kind, str(directory)).encode('utf-8')
    path = directory / f'{name}.py'
    # A link, dangling too: written through, it made a file elsewhere.
    if path.exists() or path.is_symlink():
        raise ConfigError(f'{path} exists; choose another name or remove it')
    with atomic_output(path, 'wb') as stream:
        stream.write(data)
    return path
