"""Shared service plumbing (no algorithm here): config bases, the service runtime, the step clock."""
