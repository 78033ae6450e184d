"""The memory available to this process: the machine's, its cgroup's and its address space's.

A solve that keeps its history in memory (``dense_output=True``) or builds Newton matrices asks
here before it allocates, so that it stops with an error that says what to change instead of
dying of numpy's MemoryError or being killed by the operating system.
"""
import os
import resource

#: An allocation of at most SMALL_BYTES is taken to fit without asking the system (reading
#: /proc and the cgroup's files costs about 40 us, a tenth of a small stiff solve's call).
SMALL_BYTES = 2**26


def _meminfo(field):
    """A field of /proc/meminfo in bytes, or None."""
    try:
        with open("/proc/meminfo") as meminfo:
            for line in meminfo:
                if line.startswith(field + ":"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def _cgroup_room():
    """Bytes the memory cgroup of this process may still use (limit - usage; cgroup v2's
    memory.max, v1's memory.limit_in_bytes), or None without a limit."""
    try:
        with open("/proc/self/cgroup") as cgroup:
            lines = [line.strip().split(":", 2) for line in cgroup]
    except OSError:
        return None
    for _, controllers, path in lines:
        if controllers == "":
            names, root = ("memory.max", "memory.current"), "/sys/fs/cgroup"
        elif "memory" in controllers.split(","):
            names, root = ("memory.limit_in_bytes", "memory.usage_in_bytes"), "/sys/fs/cgroup/memory"
        else:
            continue
        # inside a container the cgroup's own folder is usually mounted as the root
        for folder in (os.path.join(root, path.lstrip("/")), root):
            try:
                with open(os.path.join(folder, names[0])) as limit:
                    text = limit.read().strip()
                with open(os.path.join(folder, names[1])) as usage:
                    used = int(usage.read())
            except (OSError, ValueError):
                continue
            if text == "max" or int(text) >= 2**60:  # no limit
                break
            return int(text) - used
    return None


def address_space_room():
    """Bytes of address space left under RLIMIT_AS (what ``ulimit -v`` and
    ``resource.setrlimit`` set), or None without a limit."""
    limit, _ = resource.getrlimit(resource.RLIMIT_AS)
    if limit == resource.RLIM_INFINITY:
        return None
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith("VmSize:"):
                    return limit - int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def available_memory():
    """Bytes of memory this process may still allocate: the least of the machine's available
    memory (MemAvailable on Linux, else physical memory), the room in its cgroup and the
    room under RLIMIT_AS."""
    machine = _meminfo("MemAvailable")
    if machine is None:
        machine = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    rooms = [r for r in (_cgroup_room(), address_space_room()) if r is not None]
    return max(min([machine, *rooms]), 0)
