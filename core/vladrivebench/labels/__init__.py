"""Writing a labeler: the label files, the label store and agreement between label sources.

A labeler plugin turns :class:`~vladrivebench.LabelInput` into :class:`~vladrivebench.Labels`; this module
holds what labelers and their tools share with the core: the JSONL form of standalone CoTs
(:func:`read_jsonl`, :func:`write_jsonl`, :class:`JsonlItem`), the context of a logged step
(:func:`context_from_step`, :func:`label_input`), the content-addressed :class:`LabelStore` and its
:func:`label_key`, and Cohen's kappa between two label sources (:func:`agreement`; with the labels an item
leaves out counted as missing, :func:`load_label_source` and :func:`source_agreement`; per group of items,
:func:`agreement_by`).
"""

from vladrivebench._analysis.labels import (
    NO_GROUP,
    PROPERTIES,
    AgreementReport,
    JsonlItem,
    LabelSource,
    LabelStore,
    PropertyAgreement,
    agreement,
    agreement_by,
    content_key,
    context_from_step,
    label_input,
    label_key,
    labels_from_json,
    load_label_source,
    read_jsonl,
    read_label_source,
    source_agreement,
    write_jsonl,
)

__all__ = [
    "NO_GROUP", "PROPERTIES", "AgreementReport", "JsonlItem", "LabelSource", "LabelStore", "PropertyAgreement",
    "agreement", "agreement_by", "content_key", "context_from_step", "label_input", "label_key", "labels_from_json",
    "load_label_source", "read_jsonl", "read_label_source", "source_agreement", "write_jsonl",
]
