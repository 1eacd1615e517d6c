"""Ask the Vulkan loader what this machine can render with (the Rerun viewer's renderer), the way the viewer
itself finds it: ``dlopen("libvulkan.so.1")`` through the dynamic linker (so conda, ``/usr/lib64`` and
``LD_LIBRARY_PATH`` loaders count), then ``vkCreateInstance`` and ``vkEnumeratePhysicalDevices`` (so the
drivers the loader finds count: system, user-local or ``VK_ICD_FILENAMES``/``VK_DRIVER_FILES``).

A driver can crash its caller, so :func:`vulkan_devices` asks in a child process
(``python -m beambench.common.vulkan`` prints the answer as JSON)."""

from __future__ import annotations

import ctypes
import ctypes.util
import json
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

PROBE_TIMEOUT_S = 30.0
_INSTANCE_CREATE_INFO = 1  # VK_STRUCTURE_TYPE_INSTANCE_CREATE_INFO
_APPLICATION_INFO = 0  # VK_STRUCTURE_TYPE_APPLICATION_INFO
_API_1_0 = 1 << 22  # VK_MAKE_API_VERSION(0, 1, 0, 0)
_DEVICE_TYPES = {0: "other", 1: "integrated GPU", 2: "discrete GPU", 3: "virtual GPU", 4: "CPU (software)"}
_NAME_OFFSET = 20  # VkPhysicalDeviceProperties: four uint32 and the type enum before deviceName[256]
_PROPERTIES_BYTES = 4096  # larger than VkPhysicalDeviceProperties (824 bytes on 64-bit Linux)


@dataclass
class VulkanReport:
    """What the loader said: its library (None: no loader), the devices its drivers offer, else why none."""

    loader: str | None = None
    devices: list[str] = field(default_factory=list)
    error: str = ""

    @property
    def usable(self) -> bool:
        return bool(self.devices)


class _AppInfo(ctypes.Structure):
    _fields_ = [
        ("sType", ctypes.c_int),
        ("pNext", ctypes.c_void_p),
        ("pApplicationName", ctypes.c_char_p),
        ("applicationVersion", ctypes.c_uint32),
        ("pEngineName", ctypes.c_char_p),
        ("engineVersion", ctypes.c_uint32),
        ("apiVersion", ctypes.c_uint32),
    ]


class _CreateInfo(ctypes.Structure):
    _fields_ = [
        ("sType", ctypes.c_int),
        ("pNext", ctypes.c_void_p),
        ("flags", ctypes.c_uint32),
        ("pApplicationInfo", ctypes.POINTER(_AppInfo)),
        ("enabledLayerCount", ctypes.c_uint32),
        ("ppEnabledLayerNames", ctypes.c_void_p),
        ("enabledExtensionCount", ctypes.c_uint32),
        ("ppEnabledExtensionNames", ctypes.c_void_p),
    ]


def _load_loader() -> tuple[ctypes.CDLL, str] | None:
    """The Vulkan loader as the dynamic linker finds it, with the file it came from."""
    for name in ("libvulkan.so.1", ctypes.util.find_library("vulkan")):
        if not name:
            continue
        try:
            lib = ctypes.CDLL(name)
        except OSError:
            continue
        return lib, _mapped_path("libvulkan") or name
    return None


def _mapped_path(stem: str) -> str | None:
    """The file of a loaded library (``/proc/self/maps``), for the report."""
    try:
        maps = Path("/proc/self/maps").read_text().splitlines()
    except OSError:
        return None
    return next((line.split()[-1] for line in maps if stem in line.rsplit("/", 1)[-1]), None)


def probe_here() -> VulkanReport:
    """Load the loader, create an instance, list the physical devices (in this process)."""
    loaded = _load_loader()
    if loaded is None:
        return VulkanReport(error="no Vulkan loader (libvulkan.so.1) on the library path")
    lib, path = loaded
    app = _AppInfo(_APPLICATION_INFO, None, b"beambench doctor", 1, b"beambench", 1, _API_1_0)
    info = _CreateInfo(_INSTANCE_CREATE_INFO, None, 0, ctypes.pointer(app), 0, None, 0, None)
    instance = ctypes.c_void_p()
    lib.vkCreateInstance.restype = ctypes.c_int
    result = lib.vkCreateInstance(ctypes.byref(info), None, ctypes.byref(instance))
    if result != 0:
        why = "no Vulkan driver found" if result == -9 else f"vkCreateInstance failed ({result})"
        return VulkanReport(path, error=why)  # -9: VK_ERROR_INCOMPATIBLE_DRIVER
    try:
        count = ctypes.c_uint32(0)
        lib.vkEnumeratePhysicalDevices(instance, ctypes.byref(count), None)
        handles = (ctypes.c_void_p * count.value)()
        lib.vkEnumeratePhysicalDevices(instance, ctypes.byref(count), handles)
        devices = []
        for handle in handles[: count.value]:
            props = ctypes.create_string_buffer(_PROPERTIES_BYTES)
            lib.vkGetPhysicalDeviceProperties(ctypes.c_void_p(handle), props)
            kind = int.from_bytes(props.raw[16:20], "little")
            name = props.raw[_NAME_OFFSET : _NAME_OFFSET + 256].split(b"\0", 1)[0].decode(errors="replace")
            devices.append(f"{name} ({_DEVICE_TYPES.get(kind, 'other')})")
    finally:
        lib.vkDestroyInstance(instance, None)
    return VulkanReport(path, devices, "" if devices else "the Vulkan drivers offer no device")


def vulkan_devices(timeout_s: float = PROBE_TIMEOUT_S) -> VulkanReport:
    """:func:`probe_here` in a child process (a broken driver ends the child, not the caller)."""
    try:
        done = subprocess.run(
            [sys.executable, "-m", "beambench.common.vulkan"], capture_output=True, text=True, timeout=timeout_s
        )
    except subprocess.TimeoutExpired:
        return VulkanReport(error=f"the Vulkan loader did not answer in {timeout_s:g} s")
    try:
        data = json.loads(done.stdout.strip().splitlines()[-1])
    except (ValueError, IndexError):
        return VulkanReport(error=f"the Vulkan probe crashed (exit {done.returncode}): a broken driver?")
    return VulkanReport(data.get("loader"), list(data.get("devices", [])), str(data.get("error", "")))


if __name__ == "__main__":
    report = probe_here()
    print(json.dumps({"loader": report.loader, "devices": report.devices, "error": report.error}))
