"""Built-in dataset plugins, registered through the ``mata_eval`` entry-point group."""

from __future__ import annotations

from ..hooks import hookimpl


@hookimpl
def mata_eval_datasets() -> list[type]:
    from .dtb70 import DTB70
    from .folder import FolderDataset
    from .synthetic import SyntheticDataset
    from .uav123 import UAV20L, UAV123, UAV123_10fps
    from .uavdt import UAVDT
    from .vtuav import VTUAV

    return [UAV123, UAV123_10fps, UAV20L, DTB70, UAVDT, VTUAV, FolderDataset, SyntheticDataset]
