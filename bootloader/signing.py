"""ED25519 keys and image signatures (the ``cryptography`` package).

A signature covers :func:`protocol.image.signing_bytes` of the header (which holds the
payload's SHA-256).  Keys on disk: the private key as unencrypted PKCS#8 PEM, the public key
as SubjectPublicKeyInfo PEM; a public key may also be given as 64 hex digits or 32 raw bytes.
"""

from __future__ import annotations

from pathlib import Path

from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ed25519 import (
    Ed25519PrivateKey,
    Ed25519PublicKey,
)

from bootloader.errors import SigningError
from protocol.image import FirmwareImage, signing_bytes

PUBLIC_KEY_SIZE = 32


def generate_key_pair(private_path: Path, public_path: Path) -> bytes:
    """Write a new key pair (private PEM, public PEM); return the raw 32-byte public key."""
    key = Ed25519PrivateKey.generate()
    private_path.write_bytes(key.private_bytes(
        serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption()))
    private_path.chmod(0o600)
    public_path.write_bytes(key.public_key().public_bytes(
        serialization.Encoding.PEM, serialization.PublicFormat.SubjectPublicKeyInfo))
    return raw_public_key(key.public_key())


def raw_public_key(key: Ed25519PublicKey) -> bytes:
    """The 32 bytes a node's key record holds."""
    return key.public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)


def load_private_key(path: Path) -> Ed25519PrivateKey:
    """The ED25519 private key in the PEM file ``path``."""
    try:
        key = serialization.load_pem_private_key(Path(path).read_bytes(), password=None)
    except OSError as exc:
        raise SigningError(f"cannot read key {path}: {exc.strerror or exc}") from exc
    except (ValueError, TypeError) as exc:
        raise SigningError(f"{path} is not an unencrypted PEM private key: {exc}") from exc
    if not isinstance(key, Ed25519PrivateKey):
        raise SigningError(f"{path} holds a {type(key).__name__}, not an ED25519 key")
    return key


def load_public_key(path: Path) -> bytes:
    """The raw 32-byte ED25519 public key in ``path`` (PEM, 64 hex digits or 32 bytes)."""
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise SigningError(f"cannot read public key {path}: {exc.strerror or exc}") from exc
    if len(data) == PUBLIC_KEY_SIZE:
        return data
    text = data.strip()
    if len(text) == 2 * PUBLIC_KEY_SIZE:
        try:
            return bytes.fromhex(text.decode("ascii"))
        except (UnicodeDecodeError, ValueError):
            pass
    try:
        key = serialization.load_pem_public_key(data)
    except ValueError as exc:
        raise SigningError(f"{path} is not an ED25519 public key (PEM, hex or raw)") from exc
    if not isinstance(key, Ed25519PublicKey):
        raise SigningError(f"{path} holds a {type(key).__name__}, not an ED25519 key")
    return raw_public_key(key)


def sign_image(image: FirmwareImage, key: Ed25519PrivateKey) -> FirmwareImage:
    """``image`` with ``key``'s signature in its header slot (SIGNED set)."""
    # The SIGNED flag is part of the signed message: sign the header as it will be.
    staged = image.with_signature(b"\x01" * 64)
    return image.with_signature(key.sign(signing_bytes(staged.header)))


def signature_ok(image: FirmwareImage, public_key: bytes) -> bool:
    """True if ``image`` is signed and its signature verifies with ``public_key``."""
    if not image.header.signed:
        return False
    try:
        Ed25519PublicKey.from_public_bytes(public_key).verify(
            image.header.signature, signing_bytes(image.header))
    except (InvalidSignature, ValueError):
        return False
    return True
