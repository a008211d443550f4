"""The board files of the kinds printed as one pattern (format hec-board version 1): "aprilgrid",
"chessboard" and "charuco", their schemas and the boards they describe (each kind's module in
hec.estimator.targets). Lengths in metres. A file may leave out 'name' (the kind and the grid's
size name it) and 'size_m' (the sheet is the grid and the white around it its corner fit needs).
"""

from __future__ import annotations

from dataclasses import fields, replace
from typing import Annotated, Literal

from pydantic import Field, model_validator

from hec.estimator.io.schema import FileFormat, Flag, Integer, Positive, Text
from hec.estimator.targets import checker
from hec.estimator.targets.aprilgrid import AprilGridBoard, tag_family_size
from hec.estimator.targets.charuco import CharucoBoard, dictionary_size
from hec.estimator.targets.chessboard import ChessboardBoard
from hec.estimator.targets.qr_fit import TEMPLATE_QUIET_MODULES

_NAME = "should be a non-empty string"
_SIZE = "should be [width, height] > 0"
_LENGTH = "should be a number > 0"
_SQUARES = "should be an integer >= 2"
_DICTIONARY = "should name an OpenCV ArUco dictionary such as 'DICT_5X5_100'"
Count = Annotated[int, Field(strict=True, ge=1)]


class SheetFile(FileFormat):
    """What every board file of these kinds starts with."""

    format: Literal["hec-board"]
    version: Literal[1]
    name: Text | None = Field(None, min_length=1, description=_NAME)
    size_m: tuple[Positive, Positive] | None = Field(None, description=_SIZE)

    @classmethod
    def of(cls, board: AprilGridBoard | ChessboardBoard | CharucoBoard) -> SheetFile:
        """The file of a board: the header, its kind and every field of the board (each kind's
        dataclass fields are a subset of its file's)."""
        values = {field.name: getattr(board, field.name) for field in fields(board)}
        return cls.model_construct(format="hec-board", version=1, kind=board.kind, **values)


class AprilGridFile(SheetFile):
    """A Kalibr AprilGrid of tag36h11 tags; tag_spacing is the gap over the tag's side."""

    kind: Literal["aprilgrid"]
    tag_cols: Integer = Field(ge=1, description="should be an integer >= 1")
    tag_rows: Integer = Field(ge=1, description="should be an integer >= 1")
    tag_size_m: Positive = Field(description=_LENGTH)
    tag_spacing: Positive = Field(description=_LENGTH)
    border_bits: Integer = Field(2, ge=1, description="should be an integer >= 1")
    first_id: Integer = Field(0, ge=0, description="should be an integer >= 0")
    corner_squares: Flag = Field(False, description="must be true or false")

    @model_validator(mode="after")
    def _printable(self) -> AprilGridFile:
        board = self.board()
        last, available = board.marker_ids[-1], tag_family_size()
        if last >= available:
            raise ValueError(
                f"tags {board.first_id}-{last} do not exist: tag36h11 has IDs 0-{available - 1} "
                "(fields 'first_id', 'tag_cols', 'tag_rows')"
            )
        (width, height), margin = board.grid_size_m, board.visible_margin_m
        if width + 2 * margin > board.size_m[0] + 1e-12 or height + 2 * margin > board.size_m[1] + 1e-12:
            raise ValueError(
                f"the grid ({width * 1e3:.1f} x {height * 1e3:.1f} mm) with {margin * 1e3:.1f} mm of white "
                f"around it does not fit on the sheet 'size_m' {list(board.size_m)}"
            )
        quiet_m = TEMPLATE_QUIET_MODULES * board.feature_m
        if board.gap_m < quiet_m:
            raise ValueError(
                f"'tag_spacing' {board.tag_spacing} leaves {board.gap_m * 1e3:.1f} mm between tags; the "
                f"corner fit needs {quiet_m * 1e3:.1f} mm ({TEMPLATE_QUIET_MODULES} cells)"
            )
        return self

    def board(self) -> AprilGridBoard:
        board = AprilGridBoard(
            name=self.name or f"aprilgrid_{self.tag_cols}x{self.tag_rows}",
            size_m=self.size_m or (1.0, 1.0),  # placeholder until the grid's size is known
            tag_cols=self.tag_cols,
            tag_rows=self.tag_rows,
            tag_size_m=self.tag_size_m,
            tag_spacing=self.tag_spacing,
            border_bits=self.border_bits,
            first_id=self.first_id,
            corner_squares=self.corner_squares,
        )
        if self.size_m is None:
            margin = board.visible_margin_m
            board = replace(board, size_m=tuple(s + 2 * margin for s in board.grid_size_m))
        return board


class ChessboardFile(SheetFile):
    """A chessboard of squares_x x squares_y squares, or of inner_corners [x, y] (one less)."""

    kind: Literal["chessboard"]
    squares_x: Integer | None = Field(None, ge=2, description=_SQUARES)
    squares_y: Integer | None = Field(None, ge=2, description=_SQUARES)
    inner_corners: tuple[Count, Count] | None = Field(
        None,
        description="should be [x, y], the inner corners along each side (integers >= 1, one less than the "
        "squares)",
    )
    square_m: Positive = Field(description=_LENGTH)

    @model_validator(mode="after")
    def _readable(self) -> ChessboardFile:
        if self.inner_corners is None:
            for key in ("squares_x", "squares_y"):
                if getattr(self, key) is None:
                    raise ValueError(f"field '{key}' {_SQUARES}, got None")
        else:
            for key, count in zip(("squares_x", "squares_y"), self._squares(), strict=True):
                if getattr(self, key) not in (None, count):
                    raise ValueError(
                        f"field '{key}' {getattr(self, key)!r} disagrees with 'inner_corners' "
                        f"{list(self.inner_corners)}: {count} squares have {count - 1} inner corners"
                    )
        squares_x, squares_y = self._squares()
        if (squares_x + squares_y) % 2 == 0:
            given = (
                f"field 'inner_corners' {list(self.inner_corners)} ({squares_x}x{squares_y} squares)"
                if self.inner_corners is not None
                else f"fields 'squares_x' {squares_x} and 'squares_y' {squares_y}"
            )
            raise ValueError(
                f"{given}: one must be odd and the other even, else the board looks the same turned by half "
                "a turn and its orientation cannot be read from an image"
            )
        _check_fits(self.board(), white_squares_around=0)
        return self

    def _squares(self) -> tuple[int, int]:
        if self.inner_corners is not None:
            return self.inner_corners[0] + 1, self.inner_corners[1] + 1
        return self.squares_x, self.squares_y

    def board(self) -> ChessboardBoard:
        squares_x, squares_y = self._squares()
        return ChessboardBoard(
            self.name or f"chessboard_{squares_x}x{squares_y}",
            self.size_m or checker.grid_size_m(squares_x, squares_y, self.square_m),
            squares_x,
            squares_y,
            self.square_m,
        )


class CharucoFile(SheetFile):
    """A ChArUco board: OpenCV's CharucoBoard of that geometry and ArUco dictionary."""

    kind: Literal["charuco"]
    squares_x: Integer = Field(ge=2, description=_SQUARES)
    squares_y: Integer = Field(ge=2, description=_SQUARES)
    square_m: Positive = Field(description=_LENGTH)
    marker_m: Positive = Field(description=_LENGTH)
    dictionary: Text = Field(description=_DICTIONARY)

    @model_validator(mode="after")
    def _printable(self) -> CharucoFile:
        _check_fits(self.board(), white_squares_around=1)
        if self.marker_m >= self.square_m:
            raise ValueError(
                f"field 'marker_m' {self.marker_m} should be smaller than 'square_m' {self.square_m}"
            )
        available = dictionary_size(self.dictionary)
        if available is None:
            raise ValueError(f"field 'dictionary' {_DICTIONARY}, got {self.dictionary!r}")
        needed = self.squares_x * self.squares_y // 2
        if needed > available:
            raise ValueError(
                f"a {self.squares_x}x{self.squares_y} board needs {needed} markers; 'dictionary' "
                f"{self.dictionary} has {available}"
            )
        return self

    def board(self) -> CharucoBoard:
        width, height = checker.grid_size_m(self.squares_x, self.squares_y, self.square_m)
        return CharucoBoard(
            self.name or f"charuco_{self.squares_x}x{self.squares_y}",
            self.size_m or (width + 2 * self.square_m, height + 2 * self.square_m),
            self.squares_x,
            self.squares_y,
            self.square_m,
            self.marker_m,
            self.dictionary,
        )


def _check_fits(board: ChessboardBoard | CharucoBoard, white_squares_around: int) -> None:
    """A ValueError naming 'size_m' unless the board's grid, with white_squares_around squares of
    white around it, fits on its sheet."""
    pad = 2 * white_squares_around * board.square_m
    width, height = (s + pad for s in checker.grid_size_m(board.squares_x, board.squares_y, board.square_m))
    if width > board.size_m[0] + 1e-12 or height > board.size_m[1] + 1e-12:
        around = f" with {white_squares_around} square of white around it" if white_squares_around else ""
        raise ValueError(
            f"field 'size_m' {list(board.size_m)}: the {board.squares_x}x{board.squares_y} grid of "
            f"{board.square_m * 1e3:g} mm squares{around} ({width * 1e3:.0f} x {height * 1e3:.0f} mm) does "
            "not fit on the sheet"
        )
