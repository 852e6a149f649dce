"""``edofproj weights fetch``: download the ImageNet backbones of LPIPS and DISTS, SHA-256 checked.

    edofproj weights fetch [--backbone vgg16,alexnet] [--dir DIR] [--base-url URL]

Writes each file atomically into the folder the perceptual metrics read (default: torch's hub
cache, ``torch.hub.get_dir()/checkpoints``) and prints where it went. A file whose SHA-256 is
not the published one is refused and nothing is left behind.
"""

from __future__ import annotations

from ._common import parse_name_list


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "weights",
        help="fetch the pretrained backbone weights LPIPS and DISTS need (SHA-256 checked)",
        description=__doc__.split("\n")[0],
    )
    actions = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    fetch = actions.add_parser(
        "fetch",
        help="download vgg16 (DISTS, LPIPS-vgg) and alexnet (LPIPS) ImageNet weights",
        description="Download the ImageNet backbone files into the place the perceptual metrics read them from.",
    )
    fetch.add_argument(
        "--backbone",
        default="vgg16,alexnet",
        help="comma-separated backbones to fetch: vgg16 (DISTS, LPIPS-vgg), alexnet (LPIPS) (default: both)",
    )
    fetch.add_argument(
        "--dir",
        default=None,
        metavar="DIR",
        help="destination folder (default: torch's hub cache, where the metrics look; a folder given here "
        "is read when passed as loss.weights_dir)",
    )
    fetch.add_argument(
        "--base-url",
        default=None,
        metavar="URL",
        help="download from URL/<file name> instead of https://download.pytorch.org/models (a mirror)",
    )
    fetch.set_defaults(func=run)


def run(args) -> int:
    from ..perceptual.weights import TORCHVISION_DOWNLOAD_BASE, fetch_backbone_weights

    results = fetch_backbone_weights(
        parse_name_list(args.backbone),
        dest_dir=args.dir,
        base_url=args.base_url or TORCHVISION_DOWNLOAD_BASE,
        progress=print,
    )
    for result in results:
        print(f"{result.backbone}: {result.path} ({result.status}, SHA-256 {result.sha256[:16]}...)")
    return 0
