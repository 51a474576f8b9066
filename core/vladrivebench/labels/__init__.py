"""Writing a labeler: the label files, the label store and agreement between label sources.

A labeler plugin turns :class:`~vladrivebench.LabelInput` into :class:`~vladrivebench.Labels`; this module
holds what labelers and their tools share with the core: the JSONL form of standalone CoTs
(:func:`read_jsonl`, :func:`write_jsonl`, :class:`JsonlItem`), the context of a logged step
(:func:`context_from_step`, :func:`label_input`), the content-addressed :class:`LabelStore` and its
:func:`label_key`, and Cohen's kappa between two label sources (:func:`agreement`).
"""

from vladrivebench._analysis.labels import (
    PROPERTIES,
    AgreementReport,
    JsonlItem,
    LabelStore,
    PropertyAgreement,
    agreement,
    content_key,
    context_from_step,
    label_input,
    label_key,
    labels_from_json,
    read_jsonl,
    read_label_source,
    write_jsonl,
)

__all__ = [
    "PROPERTIES", "AgreementReport", "JsonlItem", "LabelStore", "PropertyAgreement", "agreement", "content_key",
    "context_from_step", "label_input", "label_key", "labels_from_json", "read_jsonl", "read_label_source",
    "write_jsonl",
]
